"""Episodes batched over scenes and runs, sharded over every local device: the scale path of Table 1.

A batch is E episodes, each (scene, start view, key) over the frames of S scenes held on the devices
(depth [S, V, H, W], T_wc [S, V, 4, 4]); every episode reads only its own frames (``active.rollout`` with
``scene``). The batch is split over a 1-D ``jax.sharding.Mesh`` of the local devices along its episode axis
(``mesh``; any device count, one included): each device runs its share of episodes and the episode's settings,
with no communication during the episodes, on the frames laid out one of two ways:
- ``replicate``: every device holds every scene's frames (one scene's frames for many runs: the benchmarks);
- ``split_frames``: device d holds the scenes [d S/n, (d+1) S/n) and runs their episodes (Table 1: a chunk's
  frames copied once, not n times, and 1/n of them in each device's memory; ``dispatch(..., split_scenes=True)``
  groups the episodes by the device that holds their scene, and gathers their traces back into the order given:
  one small gather across the devices after the episodes).
E is padded (to ``size`` and a multiple of the device count; split: every device's share to the largest) with
runs of an episode's scene, dropped from the result.

With a switched episode (``active.Episode.switched``) the same compiled program runs every policy row with
GR on or off (``Episode.choose``): a batch holds one row, the choice is not batched, so only its kernel runs.

    mesh = batched.mesh()                                  # all local devices
    episode = make_episode(...).switched(policies)         # one program for every row
    traces = batched.rollouts(episode.choose("random", False), depth, T_wc, scene, start, keys, mesh)

``rendered`` runs E episodes of one scene that render their frames as they move (a renderer's ``depth_fn``
called once a move inside the program) instead of reading frames from memory; one device.

Multi-host: after ``jax.distributed.initialize()`` each process runs its own share of the scenes on its local
devices with ``mesh(jax.local_devices())`` (the episodes of a scene never span processes), and the records
each writes are merged by their keys (classifier, row, scene, run).
"""

from __future__ import annotations

import enum
import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxcls import compile_cache
from jaxcls.episode import active
from jaxcls.perception import tsdf

AXIS = "episodes"


class Kernels(enum.StrEnum):
    """How XLA picks the kernels of a GPU program (a CPU ignores it). ``autotuned`` (XLA's default): timed on
    the device while compiling, the fastest kept, so two compilations of one program may pick differently and
    give results that differ in the last bits (and then, through a near tie, in a path); ``fixed``: by XLA's
    rules without timing (autotuning off), the same kernels on every compilation; ``deterministic``: fixed, and
    float scatters in a fixed order instead of atomics (the same bits from run to run too)."""

    autotuned = "autotuned"
    fixed = "fixed"
    deterministic = "deterministic"


# XLA's options for each choice of kernels (``jax.jit``'s compiler_options).
KERNEL_OPTIONS: dict[Kernels, dict | None] = {
    Kernels.autotuned: None,
    Kernels.fixed: {"xla_gpu_autotune_level": 0},
    Kernels.deterministic: {"xla_gpu_autotune_level": 0, "xla_gpu_deterministic_ops": True},
}


def mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A 1-D mesh over ``devices`` (default: every local device) named ``AXIS``."""
    devices = list(devices if devices is not None else jax.local_devices())
    return Mesh(np.asarray(devices), (AXIS,))


def _one(episode: active.Episode, depth: jax.Array, T_wc: jax.Array, scene: jax.Array, start: jax.Array,
         key: jax.Array) -> active.Trace:
    state = active.reset(episode, T_wc[scene], start, key)
    return active.rollout(episode, state, depth, T_wc, scene)[1]


@functools.lru_cache(maxsize=8)
def _traced(device_mesh: Mesh, split_scenes: bool):
    """The sharded batch for one mesh and frame layout, jitted without XLA options (what is exported)."""
    replicated, split = PartitionSpec(), PartitionSpec(AXIS)
    frames = split if split_scenes else replicated
    local = jax.vmap(_one, in_axes=(None, None, None, 0, 0, 0))
    sharded = jax.shard_map(local, mesh=device_mesh, in_specs=(replicated, frames, frames, split, split, split),
                            out_specs=split, check_vma=False)
    return jax.jit(sharded)


def _program(device_mesh: Mesh, split_scenes: bool, kernels: Kernels = Kernels.fixed):
    """The jitted, sharded batch for one mesh, frame layout and choice of kernels: compiled once per episode
    settings and shapes."""
    return compile_cache.jitted(_traced(device_mesh, split_scenes), KERNEL_OPTIONS[kernels])


@jax.jit
def _reordered(traces: active.Trace, rows: jax.Array) -> active.Trace:
    """``traces``' episodes ``rows`` (the episodes back in the order given, after ``split_scenes``' grouping)."""
    return jax.tree.map(lambda x: x[rows], traces)


def _rendered(episode: active.Episode, render, T_true: jax.Array, T_wc: jax.Array, start: jax.Array,
              keys: jax.Array, frame_key: jax.Array) -> active.Trace:
    states = jax.vmap(active.reset, in_axes=(None, None, 0, 0))(episode, T_wc, start, keys)
    step = jax.vmap(active.step, in_axes=(None, 0, 0, 0))

    def body(states: active.EpisodeState, move: jax.Array) -> tuple[active.EpisodeState, active.Trace]:
        view, skipped = states.next_view, states.done
        depth = render(T_true[view], jax.random.fold_in(frame_key, move))  # one render call for the batch
        states = step(episode, states, depth, T_wc[view])
        return states, jax.vmap(active.trace)(states, view, skipped)

    _, traces = jax.lax.scan(body, states, jnp.arange(episode.config.moves))
    return jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), traces)  # [T, E, ...] -> [E, T, ...]


_rendered_jit = jax.jit(_rendered, static_argnums=1)


def rendered(episode: active.Episode, render, T_true: jax.Array, T_wc: jax.Array, start: np.ndarray,
             keys: jax.Array, frame_key: jax.Array | None = None) -> active.Trace:
    """E episodes of one scene whose frames are rendered as they move, on one device: each move renders the E
    episodes' next views in one call of ``render(T_true [E, 4, 4], key) -> depth [E, H, W]`` (m, traceable: a
    renderer's ``depth_fn(E)``, e.g. MuJoCo Warp's batch renderer on a GPU or MJX's ray caster on a CPU, with a
    sensor model drawn from ``key``, the move's fold of ``frame_key``) inside the episodes' program
    (``lax.scan`` over the moves, the step vmapped over the episodes). T_true [V, 4, 4]: the viewpoints' true
    poses (rendered from); T_wc [V, 4, 4]: the poses the episode is told; start [E], keys [E]. Returns a
    ``Trace`` with [E, T, ...] device leaves: ``rollouts``' traces for the same frames rendered beforehand."""
    if episode.config.off_grid:
        raise ValueError("rendered: off_grid views are not rendered here yet (the fixed viewpoints only); use "
                         "runner.run with a sources.Rendered source")
    start = jnp.asarray(start, jnp.int32)
    if T_true.shape != T_wc.shape or T_wc.ndim != 3 or T_wc.shape[1:] != (4, 4):
        raise ValueError(f"rendered: T_true and T_wc must both be [V, 4, 4], got {T_true.shape} and {T_wc.shape}")
    if start.ndim != 1 or keys.shape[0] != start.shape[0]:
        raise ValueError(f"rendered: start [E] and keys [E, ...] must agree, got {start.shape} and {keys.shape}")
    frame_key = jax.random.PRNGKey(0) if frame_key is None else frame_key
    return _rendered_jit(episode, render, jnp.asarray(T_true, jnp.float32), jnp.asarray(T_wc, jnp.float32), start,
                         keys, frame_key)


def replicate(x: np.ndarray | jax.Array, device_mesh: Mesh | None = None, rows: int | None = None) -> jax.Array:
    """``x`` as float32 on every device of ``device_mesh`` (frames shared by the calls of a chunk: copied once),
    its first axis padded to ``rows`` with copies of ``x[0]`` (a shorter set of scenes keeps a program's shape,
    so it does not compile again)."""
    device_mesh = device_mesh or mesh()
    return jax.device_put(_padded(x, rows), NamedSharding(device_mesh, PartitionSpec()))


def split_frames(x: np.ndarray | jax.Array, device_mesh: Mesh | None = None, rows: int | None = None) -> jax.Array:
    """``x`` [S, ...] as float32 split by scene over the devices of ``device_mesh`` (device d holds the rows
    [d S'/n, (d+1) S'/n)), its first axis padded with copies of ``x[0]`` to ``rows`` (at least) and a multiple of
    the devices: the frames of ``dispatch(..., split_scenes=True)``."""
    device_mesh = device_mesh or mesh()
    n = device_mesh.devices.size
    S = max(x.shape[0], rows or 0)
    return jax.device_put(_padded(x, S + (-S % n)), NamedSharding(device_mesh, PartitionSpec(AXIS)))


def _padded(x: np.ndarray | jax.Array, rows: int | None) -> np.ndarray | jax.Array:
    """``x`` as float32, its first axis padded to ``rows`` with copies of ``x[0]``: on the host for a NumPy
    ``x`` (put from there straight to its devices, not first whole onto one), where it lies for a JAX one."""
    xp = np if isinstance(x, np.ndarray) else jnp
    x = xp.asarray(x, xp.float32)
    if rows is not None and rows > x.shape[0]:
        x = xp.concatenate([x, xp.broadcast_to(x[:1], (rows - x.shape[0], *x.shape[1:]))])
    return x


def dispatch(episode: active.Episode, depth: jax.Array, T_wc: jax.Array, scene: np.ndarray, start: np.ndarray,
             keys: jax.Array, device_mesh: Mesh | None = None, size: int | None = None,
             split_scenes: bool = False, kernels: Kernels = Kernels.fixed) -> active.Trace:
    """E episodes over the frames of S scenes, started on the devices and returned at once (JAX dispatches
    asynchronously; ``fetch`` waits for them): depth [S, V, H, W] m (0 = no return), T_wc [S, V, 4, 4] every
    viewpoint's frame; scene [E] i32 each episode's scene, start [E] i32 its start view, keys [E] its key. A
    ``Trace`` with [E', T, ...] device leaves, E' = E padded to ``size`` (at least; one compiled shape for a
    run's calls, the last shorter one too, as long as no device's share exceeds size / n) and to a multiple of
    the devices. Sharded over ``device_mesh``
    (default: all local devices). Frames already on the device stay there. ``split_scenes``: the frames are
    split by scene over the devices (``split_frames``; S a multiple of the devices), each episode runs on the
    device that holds its scene (every device's share padded to the largest), and the first E rows of the
    result are the episodes in the order given. ``kernels``: how XLA picks the program's GPU kernels
    (``Kernels``; ``fixed``: the same records from every compilation of the program)."""
    device_mesh = device_mesh or mesh()
    scene, start = np.asarray(scene, np.int32), np.asarray(start, np.int32)
    E, S, V = len(scene), depth.shape[0], depth.shape[1]
    if depth.ndim != 4 or T_wc.shape != (S, V, 4, 4):
        raise ValueError(f"batched: depth must be [S, V, H, W] and T_wc [S, V, 4, 4], got {depth.shape} and "
                         f"{T_wc.shape}")
    if not (start.shape == (E,) and keys.shape[0] == E):
        raise ValueError(f"batched: scene, start and keys need one entry per episode, got {scene.shape}, "
                         f"{start.shape} and {keys.shape}")
    if not E:
        raise ValueError("batched: no episodes to run")
    if scene.min() < 0 or scene.max() >= S or start.min() < 0 or start.max() >= V:
        raise ValueError(f"batched: scenes must lie in 0..{S - 1} and start views in 0..{V - 1}")
    n = device_mesh.devices.size
    padded = max(E, size or 0)
    order = None
    if split_scenes:
        if S % n:
            raise ValueError(f"batched: {S} scenes do not split over {n} devices (batched.split_frames pads them)")
        scene, start, keys, order = _grouped(scene, start, keys, S // n, n, -(-padded // n))
    else:
        pad = padded - E + (-padded % n)
        if pad:  # copies of the first episode, dropped by fetch
            scene = np.concatenate([scene, np.repeat(scene[:1], pad)])
            start = np.concatenate([start, np.repeat(start[:1], pad)])
            keys = jnp.concatenate([keys, jnp.repeat(keys[:1], pad, axis=0)])
    args = _placed(episode, depth, T_wc, scene, start, keys, device_mesh, split_scenes)
    # (with the compilation cache on, a later process compiles the program kept on disk instead of tracing it)
    traces = compile_cache.exported(_traced(device_mesh, split_scenes), args, "batched_episodes",
                                    KERNEL_OPTIONS[kernels])(*args)
    return traces if order is None else _reordered(traces, order)


def _placed(episode: active.Episode, depth: jax.Array | jax.ShapeDtypeStruct, T_wc: jax.Array, scene: np.ndarray,
            start: np.ndarray, keys: jax.Array, device_mesh: Mesh, split_scenes: bool) -> tuple:
    """The program's arguments on their devices (frames split by scene or replicated, the episodes split); a
    ``jax.ShapeDtypeStruct`` ``depth`` (frames not yet rendered) becomes one with its sharding."""
    volume = episode.spec.config.volume
    tsdf.check_kernel_batch(volume.kernel, volume.storage, volume.resolution, len(scene) // device_mesh.devices.size,
                            device_mesh.devices.flat[0].platform)
    split = NamedSharding(device_mesh, PartitionSpec(AXIS))
    frames = split if split_scenes else NamedSharding(device_mesh, PartitionSpec())
    depth = (jax.ShapeDtypeStruct(depth.shape, jnp.float32, sharding=frames) if isinstance(depth, jax.ShapeDtypeStruct)
             else jax.device_put(jnp.asarray(depth, jnp.float32), frames))
    return (jax.device_put(episode, NamedSharding(device_mesh, PartitionSpec())), depth,
            jax.device_put(jnp.asarray(T_wc, jnp.float32), frames),
            jax.device_put(scene, split), jax.device_put(start, split), jax.device_put(keys, split))


def prepare(episode: active.Episode, frames: tuple[int, int, int, int], size: int, device_mesh: Mesh | None = None,
            split_scenes: bool = False, kernels: Kernels = Kernels.fixed) -> None:
    """Read and compile (with the compilation cache on: load) the program that ``dispatch`` runs for ``episode``
    over frames of shape ``frames`` = (S, V, H, W) in calls of ``size`` episodes (a multiple of the devices,
    each device's share at most size / n), before the frames exist: e.g. on a background thread
    (``compile_cache.ahead``) while the host builds their renderer or renders them (never beside a render under
    MuJoCo Warp's own graph capture: ``compile_cache.ahead`` says why), so that the first call finds it ready.
    Without the cache nothing is done here (the first call compiles)."""
    if not compile_cache.enabled():
        return
    device_mesh = device_mesh or mesh()
    n = device_mesh.devices.size
    rows = n * -(-size // n)
    S, V = frames[0], frames[1]
    key = jax.random.PRNGKey(0)
    args = _placed(episode, jax.ShapeDtypeStruct(tuple(frames), jnp.float32), np.zeros((S, V, 4, 4), np.float32),
                   np.zeros(rows, np.int32), np.zeros(rows, np.int32), jnp.broadcast_to(key, (rows, *key.shape)),
                   device_mesh, split_scenes)
    compile_cache.exported(_traced(device_mesh, split_scenes), args, "batched_episodes", KERNEL_OPTIONS[kernels])


def _grouped(scene: np.ndarray, start: np.ndarray, keys: jax.Array, per: int, n: int, least: int
             ) -> tuple[np.ndarray, np.ndarray, jax.Array, np.ndarray]:
    """The episodes grouped by the device that holds their scene (device d: scenes [d per, (d+1) per)), each
    device's share padded to the largest (and to ``least``) with runs of its first scene: (local scene [n m],
    start, keys, rows [n m]: the given episodes' places first, then the padding's)."""
    owner = scene // per
    shares = [np.flatnonzero(owner == d) for d in range(n)]
    m = max(least, *(len(share) for share in shares))
    slots = np.full((n, m), -1, np.int64)  # the episode in each device's place, -1: padding
    for d, share in enumerate(shares):
        slots[d, :len(share)] = share
    slots = slots.reshape(-1)
    real, first = slots >= 0, np.repeat(np.arange(n) * per, m)
    pick = np.maximum(slots, 0)
    local = np.where(real, scene[pick], first) - first
    rows = np.concatenate([np.flatnonzero(real)[np.argsort(slots[real])], np.flatnonzero(~real)])
    return (local.astype(np.int32), np.where(real, start[pick], 0).astype(np.int32), jnp.asarray(keys)[pick],
            rows.astype(np.int32))


def fetch(traces: active.Trace, episodes: int) -> active.Trace:
    """The first ``episodes`` episodes of ``dispatch``'s traces on the host (NumPy), once they are done."""
    return jax.tree.map(lambda x: np.asarray(x)[:episodes], jax.device_get(traces))


def rollouts(episode: active.Episode, depth: jax.Array, T_wc: jax.Array, scene: np.ndarray, start: np.ndarray,
             keys: jax.Array, device_mesh: Mesh | None = None, split_scenes: bool = False,
             kernels: Kernels = Kernels.fixed) -> active.Trace:
    """``dispatch`` then ``fetch``: a ``Trace`` with [E, T, ...] NumPy leaves."""
    return fetch(dispatch(episode, depth, T_wc, scene, start, keys, device_mesh, split_scenes=split_scenes,
                          kernels=kernels), len(scene))


__all__ = ["AXIS", "KERNEL_OPTIONS", "Kernels", "dispatch", "fetch", "mesh", "prepare", "rendered", "replicate",
           "rollouts", "split_frames"]
