"""Whole episodes batched on one device: ``active.rollout`` (T moves under one ``lax.scan``) vmapped over
episodes of one scene from different start views, as issue 23's larger runs will use it.

    python benchmarks/episode_batched.py --save data/gpu/scene3.npz          # on a machine with MuJoCo
    python benchmarks/episode_batched.py --frames data/gpu/scene3.npz --batch 1 16 64 [--out BENCHMARKS.md]
        [--tracking frame_to_model reported] [--storage float32 compact] [--precision float32 tf32]

Every combination of camera tracking (``perception.tracking.mode``), the volume's storage
(``perception.volume.storage``) and PointNet's products (``perception.classification_precision``) is a
variant, and so are the batch's memory layouts (``--slabs``, ``--segments-per-pass``; by default 8 and 1, the fusion in
slabs and PointNet a segment at a time, as the scale configs run it), the tracking's pyramid levels
(``--tracking-levels``), the fusion's kernel (``--fusion xla pallas``) and PointNet's pooling (``--pooling xla
pallas``); each batch size runs every variant, their repeats interleaved. Reports episodes/s and moves/s, the
first call (compilation), the program's device memory per episode (XLA's temporaries of the batch over B:
``compiled.memory_analysis``), the final F1 of the target objects pooled over the batch (prior and refined), and
the share of episodes whose path and final labels equal the first variant's; ``--trace FILE`` writes each
episode's path and final labels (JSON) to compare with another device. ``--fit B ...`` compiles Table 1's own
program (``episode.batched``) at B episodes, checks it against the device's memory and times one call where it
fits.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
import itertools
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import io, metrics, precision, report
from jaxcls.episode import active, batched, scoring, setup
from jaxcls.geometry import Intrinsics
from jaxcls.perception import tsdf
from jaxcls.perception.pointnet import PoolingKernel
from jaxcls.precision import MatmulPrecision


def save_frames(path: str, seed: int) -> None:
    """Render scene ``seed`` of the default world from every viewpoint (depth in mm, uint16) to ``path``."""
    from jaxcls.world import WorldConfig, make_world

    world = make_world(WorldConfig(backend="mujoco"), seed=seed)
    depth, T_wc, _, _ = world.measure(jax.random.PRNGKey(seed), np.arange(len(world.viewpoints)))
    with io.atomic_write(path) as f:
        np.savez_compressed(f, depth_mm=np.round(depth * 1000).astype(np.uint16), T_wc=T_wc,
                            scene_json=np.array(json.dumps(world.scene.to_dict())))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default="data/gpu/scene3.npz")
    parser.add_argument("--save", help="render the frames file here (needs MuJoCo) and stop")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--batch", type=int, nargs="*", default=[1, 16, 64])
    parser.add_argument("--moves", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--trace", help="write each episode's path and final labels (JSON) here")
    parser.add_argument("--tracking", nargs="+", default=["frame_to_model"], choices=["frame_to_model", "reported"],
                        help="perception.tracking.mode of the episodes (several: compared, interleaved)")
    parser.add_argument("--storage", nargs="+", default=["float32"], choices=["float32", "compact"],
                        help="perception.volume.storage (several: compared, interleaved)")
    parser.add_argument("--precision", nargs="+", default=["float32"], choices=[p.value for p in MatmulPrecision],
                        help="perception.classification_precision (several: compared, interleaved)")
    parser.add_argument("--slabs", type=int, nargs="+", default=[8],
                        help="perception.volume.slabs (the batch's memory layout; the library's default is 1; "
                             "several: compared, interleaved)")
    parser.add_argument("--fusion", nargs="+", default=["xla"], choices=[k.value for k in tsdf.FusionKernel],
                        help="perception.volume.kernel (tsdf.FusionKernel: the fusion vectorised or one Pallas kernel "
                             "in place; several: compared, interleaved)")
    parser.add_argument("--pooling", nargs="+", default=["xla"], choices=[k.value for k in PoolingKernel],
                        help="perception.classification_pooling (pointnet.PoolingKernel: PointNet's pooled layers as "
                             "XLA's product then max, or one Pallas kernel; bfloat16 only; several: compared, "
                             "interleaved)")
    parser.add_argument("--segments-per-pass", type=int, nargs="+", default=[1],
                        help="perception.shapes.segments_per_pass (PointNet; the library's default is 0: all; "
                             "several: compared, interleaved)")
    parser.add_argument("--tracking-levels", type=int, nargs="+", default=[],
                        help="perception.tracking.levels (the tracking's pyramid; default: the library's; several: "
                             "compared, interleaved)")
    parser.add_argument("--fit", type=int, nargs="*", default=[],
                        help="batch sizes of Table 1's program (episode.batched): its device memory against the "
                             "device's, and one call timed where it fits")
    parser.add_argument("--devices", type=int, nargs="*", default=[],
                        help="device counts: each batch of --batch runs as Table 1's program (episode.batched) sharded "
                             "over the first N local devices, the counts interleaved, instead of plain vmap")
    parser.add_argument("--kernels", nargs="+", default=["fixed"], choices=[k.value for k in batched.Kernels],
                        help="with --devices: how XLA picks the GPU kernels of Table 1's program (batched.Kernels; "
                             "several: compared, interleaved)")
    parser.add_argument("--render", action="store_true",
                        help="each batch also renders its frames as it moves (episode.batched.rendered: the scene's "
                             "renderer, warp on a GPU, MJX's ray caster on a CPU, and the world's sensor inside the "
                             "timed program), against the frames in memory, interleaved")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    if any(n < 1 or n > len(jax.local_devices()) for n in args.devices):
        parser.error(f"--devices: each count must lie in 1..{len(jax.local_devices())} (the local devices)")
    if args.save:
        save_frames(args.save, args.seed)
        print(f"wrote {args.save}")
        return
    precision.full_float32_matmuls()  # camera poses need it on GPUs

    from jaxcls.world.objects import object_set_from_config
    from jaxcls.world.scenes import Scene

    with np.load(args.frames) as f:
        depth = jnp.asarray(f["depth_mm"].astype(np.float32) / 1000.0)
        T_wc = jnp.asarray(f["T_wc"], jnp.float32)
        scene = Scene.from_dict(json.loads(str(f["scene_json"])), source=args.frames)
    object_set = object_set_from_config(scene.object_set)
    truth = scoring.Truth.from_scene(scene, object_set)
    perception = setup.episode_perception()
    episodes = {}
    levels = args.tracking_levels or [perception.tracking.levels]
    for mode, storage, product, slabs, per_pass, level, fusion, pooling in itertools.product(
            args.tracking, args.storage, args.precision, args.slabs, args.segments_per_pass, levels, args.fusion,
            args.pooling):
        settings = setup.ActiveConfig(episode=active.EpisodeConfig(moves=args.moves), perception=dataclasses.replace(
            perception, tracking=dataclasses.replace(perception.tracking, mode=mode, levels=level),
            volume=dataclasses.replace(perception.volume, storage=storage, slabs=slabs,
                                       kernel=tsdf.FusionKernel(fusion)),
            shapes=dataclasses.replace(perception.shapes, segments_per_pass=per_pass),
            classification_precision=product, classification_pooling=PoolingKernel(pooling)))
        name = f"{mode}/{storage}/{product}"  # (the layout named where several are compared)
        name += f"/slabs {slabs}" if len(args.slabs) > 1 else ""
        name += f"/segments a pass {per_pass}" if len(args.segments_per_pass) > 1 else ""
        name += f"/fusion {fusion}" if len(args.fusion) > 1 or fusion != "xla" else ""
        name += f"/pooling {pooling}" if len(args.pooling) > 1 or pooling != "xla" else ""
        name += f"/tracking levels {level}" if len(levels) > 1 or level != perception.tracking.levels else ""
        episodes[name] = setup.make_episode(settings, object_set, Intrinsics.kinect_v1(),
                                                                     scene.table_height)
    reset = jax.jit(jax.vmap(active.reset, in_axes=(None, None, 0, 0)))
    rollout = jax.jit(jax.vmap(active.rollout, in_axes=(None, 0, None, None)))
    rows, traces = [], []
    M = len(object_set.classes)
    for B in [] if args.devices or args.render else args.batch:  # (--devices, --render: their own tables)
        starts = jnp.asarray(np.random.default_rng(B).integers(0, T_wc.shape[0], B), jnp.int32)
        keys = jax.random.split(jax.random.PRNGKey(B), B)
        first, times, final, trace, memory = {}, {m: [] for m in episodes}, {}, {}, {}
        for episode in episodes.values():
            volume = episode.spec.config.volume
            tsdf.check_kernel_batch(volume.kernel, volume.storage, volume.resolution, B, jax.devices()[0].platform)
        for mode, episode in episodes.items():
            states = jax.eval_shape(reset, episode, T_wc, starts, keys)
            analysis = rollout.lower(episode, states, depth, T_wc).compile().memory_analysis()
            memory[mode] = (analysis.temp_size_in_bytes + analysis.output_size_in_bytes) / B if analysis else np.nan
            t0 = time.perf_counter()
            final[mode], trace[mode] = jax.block_until_ready(rollout(episode, reset(episode, T_wc, starts, keys),
                                                                     depth, T_wc))
            first[mode] = time.perf_counter() - t0
        for _ in range(args.repeats):
            for mode, episode in episodes.items():
                t0 = time.perf_counter()
                jax.block_until_ready(rollout(episode, reset(episode, T_wc, starts, keys), depth, T_wc))
                times[mode].append(time.perf_counter() - t0)
        base = next(iter(episodes))
        for mode in episodes:
            t = float(np.median(times[mode]))
            true, predicted = [], []  # per episode: the targets' true and [prior, refined] labels
            for b in range(B):
                r = jax.tree.map(lambda a, b=b: np.asarray(a[b]), final[mode].refinement)
                centroid = np.asarray(active.centroids(jax.tree.map(lambda a, b=b: a[b], final[mode].observation)))
                labels = scoring.object_labels(truth, centroid, r.valid, np.stack([r.prior, r.refined]))
                predicted.append(labels[:, truth.target])
                true.append(truth.label[truth.target])
            true, predicted = np.concatenate(true), np.concatenate(predicted, axis=1)
            scores = {label: metrics.classification_scores(true, predicted[i], M).f1
                      for i, label in enumerate(("prior", "refined"))}
            same = (np.all(np.asarray(trace[mode].view) == np.asarray(trace[base].view), axis=1)
                    & np.all(np.asarray(final[mode].refinement.refined) == np.asarray(final[base].refinement.refined),
                             axis=1))
            rows.append((B, mode, report.device_name(), f"{first[mode]:.1f}", f"{t * 1e3:.0f}", f"{B / t:.1f}",
                         f"{B * args.moves / t:.0f}", f"{memory[mode] / 1e6:.1f}", f"{scores['prior']:.3f}",
                         f"{scores['refined']:.3f}", f"{np.mean(same):.2f}"))
            print(rows[-1], flush=True)
            traces += [{"batch": B, "variant": mode, "start": int(starts[b]),
                        "path": np.asarray(trace[mode].view[b]).tolist(),
                        "refined": np.asarray(final[mode].refinement.refined[b]).tolist(),
                        "valid": np.asarray(final[mode].refinement.valid[b]).tolist()} for b in range(min(B, 16))]
        del final, trace
    if args.devices:
        report.publish(report.section(
            f"Batched episodes sharded over devices ({args.moves} moves, 640x480, one scene)", argv,
            ("episodes", "devices", "variant", "kernels", "device", "first call s (compile)", "median ms per batch",
             "moves/s", "speed-up over the first", "same path and labels as the first",
             "same path and labels as its own first call"),
            sharded_rows(episodes, depth, T_wc, args.batch, args.devices, args.kernels, args.repeats,
                         args.moves, traces),
            intro="Table 1's program (`episode.batched`: reset and rollout per episode, traces out) over B episodes of "
                  "one scene, split over a 1-D mesh of the first N local devices (B / N episodes each, no "
                  "communication), its GPU kernels picked as `batched.Kernels` says (autotuned: "
                  "XLA's default; fixed: without timing them; deterministic: fixed, scatters in order); the "
                  "programs' repeats interleaved, then each called once more and "
                  "compared with its first call; frames in device memory."), args.out)
    if args.render:
        report.publish(report.section(
            f"Batched episodes rendering their frames as they move ({args.moves} moves, 640x480, one scene)", argv,
            ("episodes", "variant", "frames", "device", "first call s (compile)", "median ms per batch", "moves/s",
             "share of the frames in memory's moves/s", "same path and labels as frames in memory"),
            rendered_rows(episodes, depth, T_wc, scene, args.batch, args.repeats, args.moves),
            intro="One device. Frames in memory: Table 1's program (`episode.batched`) over the frames rendered "
                  "beforehand; rendered: `episode.batched.rendered`, each move's frames drawn by the scene's "
                  "renderer and the world's sensor model inside the timed program (its noise drawn a move at a "
                  "time, so paths may differ); repeats interleaved."), args.out)
    fits = []
    limit = (jax.devices()[0].memory_stats() or {}).get("bytes_limit", np.nan)
    program = batched._program(batched.mesh(), False)  # Table 1's program: reset and rollout inside, traces out
    for B in args.fit:
        scene = jnp.zeros(B, jnp.int32)
        starts = jnp.asarray(np.random.default_rng(B).integers(0, T_wc.shape[0], B), jnp.int32)
        keys = jax.random.split(jax.random.PRNGKey(B), B)
        for mode, episode in episodes.items():
            t0 = time.perf_counter()
            compiled = program.lower(episode, depth[None], T_wc[None], scene, starts, keys).compile()
            compile_s = time.perf_counter() - t0
            analysis = compiled.memory_analysis()
            total = analysis.temp_size_in_bytes + analysis.output_size_in_bytes + analysis.argument_size_in_bytes
            ran = "-"
            fits_device = not total > limit  # (no limit known: a CPU)
            if fits_device:  # run it: the batch fits, and how fast it goes
                jax.block_until_ready(compiled(episode, depth[None], T_wc[None], scene, starts, keys))
                t0 = time.perf_counter()
                jax.block_until_ready(compiled(episode, depth[None], T_wc[None], scene, starts, keys))
                ran = f"{B * args.moves / (time.perf_counter() - t0):.0f}"
            fits.append((B, mode, report.device_name(), f"{compile_s:.0f}", f"{total / 1e9:.1f}",
                         f"{total / B / 1e6:.1f}", f"{limit / 1e9:.1f}", "yes" if fits_device else "no", ran))
            print(fits[-1], flush=True)
    if args.trace:
        io.write_json(args.trace, traces)
    if rows:
        report.publish(report.section(
            f"Whole episodes batched ({args.moves} moves, 640x480, one scene)", argv,
            ("episodes", "tracking/storage/PointNet products", "device", "first call s (compile)",
             "median ms per batch", "episodes/s", "moves/s", "device MB per episode", "F1 prior (pooled)",
             "F1 refined (pooled)",
             f"same path and labels as {next(iter(episodes))}"), rows,
            intro=f"`active.rollout` vmapped over episodes from random start views of scene {args.frames} (100 "
                  "viewpoints), the episode's defaults (`setup.ActiveConfig()`); frames in device memory."),
            args.out)
    if fits:
        report.publish(report.section(
            "Batched episodes against device memory", argv,
            ("episodes", "tracking/storage/PointNet products", "device", "compile s", "program GB (XLA's analysis)",
             "MB per episode", "device GB available", "fits", "moves/s (one call)"), fits,
            intro="Table 1's program (`episode.batched`: reset and rollout per episode, traces out) over B episodes of "
                  "one scene: its arguments, outputs and temporaries as XLA's memory analysis gives them, against "
                  "the device's limit (`XLA_PYTHON_CLIENT_MEM_FRACTION`); where it fits, one call timed after a "
                  "first."), args.out)


def interleaved(runs: dict, repeats: int) -> tuple[dict, dict, dict, dict]:
    """Each of ``runs`` (name -> a call returning a ``Trace``) once (its first call: compiling), ``repeats`` times
    round-robin, then once more: ({name: first call s}, {name: median s}, {name: its first traces on the host},
    {name: the share of episodes whose path and labels in the last call equal the first call's})."""
    first, traces = {}, {}
    for name, run in runs.items():
        t0 = time.perf_counter()
        traces[name] = jax.device_get(run())
        first[name] = time.perf_counter() - t0
    times, _ = report.interleaved(runs, repeats)
    again = {name: same_paths(jax.device_get(run()), traces[name]) for name, run in runs.items()}
    return first, {name: float(np.median(t)) for name, t in times.items()}, traces, again


def same_paths(traces: active.Trace, base: active.Trace) -> float:
    """The share of episodes whose path and final refined labels equal ``base``'s."""
    return float(np.mean(np.all(traces.view == base.view, axis=1)
                         & np.all(traces.refinement.refined[:, -1] == base.refinement.refined[:, -1], axis=1)))


def rendered_rows(episodes: dict[str, active.Episode], depth: jax.Array, T_wc: jax.Array, scene, batches: list[int],
                  repeats: int, moves: int) -> list[tuple]:
    """Per batch size B and variant: B episodes over frames in memory against the same episodes rendering
    their frames as they move (``batched.rendered``), repeats interleaved: the table's rows."""
    from jaxcls.world import WorldConfig, make_world
    from jaxcls.world.render.sensor import apply_sensor

    world = make_world(WorldConfig(backend="warp" if jax.default_backend() == "gpu" else "mjx"), scene=scene)
    T_true = jnp.asarray(world.viewpoints, jnp.float32)
    mesh = batched.mesh(jax.local_devices()[:1])
    rows = []
    for B, (mode, episode) in itertools.product(batches, episodes.items()):
        depth_fn, sensor = world.renderer.depth_fn(B), world.config.sensor

        def render(T: jax.Array, key: jax.Array, depth_fn=depth_fn, sensor=sensor) -> jax.Array:
            return apply_sensor(key, depth_fn(T), world.intrinsics, sensor)

        scenes = np.zeros(B, np.int32)
        starts = np.random.default_rng(B).integers(0, T_wc.shape[0], B).astype(np.int32)
        keys = jax.random.split(jax.random.PRNGKey(B), B)
        runs = {"in memory": functools.partial(batched.dispatch, episode, depth[None], T_wc[None], scenes, starts,
                                               keys, mesh),
                "rendered": functools.partial(batched.rendered, episode, render, T_true, T_wc, starts, keys)}
        rows += [(B, mode, name, *cells) for name, cells in compared(runs, "in memory", repeats, B * moves).items()]
    return rows


def compared(runs: dict, base, repeats: int, moves: int, kept: list | None = None) -> dict:
    """``interleaved`` ``runs`` of ``moves`` moves each, as table cells per run: (device, first call s, median ms,
    moves/s, speed-up over ``base``'s run, share of paths and labels equal to ``base``'s[, and to its own first
    call's where ``kept`` is given]); each printed. ``kept``: each run's every episode (name, path, final refined
    labels) appended, to compare with another process (``--trace``)."""
    first, times, traces, again = interleaved(runs, repeats)
    cells = {}
    for name, t in times.items():
        cells[name] = (report.device_name(), f"{first[name]:.1f}", f"{t * 1e3:.0f}", f"{moves / t:.0f}",
                       f"{times[base] / t:.2f}", f"{same_paths(traces[name], traces[base]):.2f}",
                       *([f"{again[name]:.2f}"] if kept is not None else []))
        print(name, cells[name], flush=True)
        if kept is not None:
            leaves = [np.asarray(x) for x in jax.tree.leaves(traces[name])]
            kept += [{"run": str(name), "path": np.asarray(traces[name].view[b]).tolist(),
                      "refined": np.asarray(traces[name].refinement.refined[b, -1]).tolist(),
                      "bits": hashlib.sha256(b"".join(x[b].tobytes() for x in leaves)).hexdigest()[:16]}
                     for b in range(traces[name].view.shape[0])]
    return cells


def sharded_rows(episodes: dict[str, active.Episode], depth: jax.Array, T_wc: jax.Array, batches: list[int],
                 device_counts: list[int], kernels: list[str], repeats: int, moves: int, kept: list) -> list[tuple]:
    """Per batch size B and variant, B episodes through ``episode.batched`` over each count of local devices and
    each choice of kernels (``kernels``: ``batched.Kernels`` values), their repeats interleaved:
    the table's rows (moves/s, speed-up over the first, the share of episodes whose path and final labels equal
    the first's, and the same against the program's own first call). Every episode appended to ``kept``."""
    meshes = {n: batched.mesh(jax.local_devices()[:n]) for n in device_counts}
    rows = []
    for B, (mode, episode) in itertools.product(batches, episodes.items()):
        scene = np.zeros(B, np.int32)
        starts = np.random.default_rng(B).integers(0, T_wc.shape[0], B).astype(np.int32)
        keys = jax.random.split(jax.random.PRNGKey(B), B)
        frames = {n: (batched.replicate(depth[None], m), batched.replicate(T_wc[None], m)) for n, m in meshes.items()}
        runs = {(n, k): functools.partial(batched.dispatch, episode, *frames[n], scene, starts, keys, m,
                                          kernels=batched.Kernels(k))
                for (n, m), k in itertools.product(meshes.items(), kernels)}
        episodes_kept: list = []
        cells = compared(runs, next(iter(runs)), repeats, B * moves, episodes_kept)
        for (n, k), c in cells.items():
            rows.append((B, n, mode, k, *c))
        kept += [dict(e, batch=B, variant=mode) for e in episodes_kept]
        del frames
    return rows


if __name__ == "__main__":
    main()
