"""The paper's evaluation protocol (Sec. 4) as the rows of its Table 1, run on a scene's fixed viewpoints.

A row is a typed entry of ``ROWS``: how its episodes run (``Kind``), the policy, GR on or off, and GR's
model library. Every row but the upper bounds runs ``runs`` episodes per scene from seeded random start
views (``start_views``) with T moves; the episodes of one scene run together, ``vmap``ped over the runs
(``rollouts``: one ``jit`` per row, the whole episode a ``lax.scan``):

- ``single`` (PointNetSingle): one move from the start view;
- ``full`` (PointNetFull): every viewpoint fused, then one segmentation, classification and GR
  (``all_views``): the upper bound of any policy; one episode per scene (it has no start view);
- ``policy``: the NBV policy's T moves (``Random``, ``VisNoOccl``, ``VisOccl``, ``VisOcclHist``, and the
  policies beyond the paper);
- ``oracle``: at each move every candidate's real next view is fused, segmented, classified and refined,
  and the one whose refined labels score the best true F1 is taken (``oracle_rollouts``): the upper bound of
  any next-best-view policy.
- ``oracle_rollout`` (OracleRolloutGR): the same, each candidate scored by its true F1 at T with InfoGain
  making the moves after it (``Label.rollout``): one step of policy improvement over InfoGain, not greedy.

``episode_record`` turns an episode into its JSON record (the target objects' labels after every move,
matched to the segments by Hungarian assignment, ``scoring.object_labels``); ``per_scene`` gathers a row's
records into what ``metrics.scene_interval`` and ``metrics.paired_difference`` resample.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import itertools
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from jaxcls import compile_cache, devices, metrics
from jaxcls.episode import active, batched, scoring, setup
from jaxcls.episode.setup import ActiveConfig
from jaxcls.geometry import Intrinsics
from jaxcls.perception import observation, pointnet, tracking
from jaxcls.planning import nbv
from jaxcls.world.objects import ObjectSet


class Kind(enum.Enum):
    SINGLE = "single"
    FULL = "full"
    POLICY = "policy"
    ORACLE = "oracle"


class Label(enum.Enum):
    """What the oracle scores a candidate by (``oracle_rollouts``)."""

    greedy = "greedy"  # its true F1 after its move (the oracle row: one move ahead)
    rollout = "rollout"  # its true F1 at T, the episode's own policy taking the moves after it (a base policy's
    # rollout: picking its best is one step of policy improvement over that policy)


@dataclasses.dataclass(frozen=True)
class Row:
    """A row of Table 1: ``label`` as printed; ``kind``; the NBV ``policy`` (``nbv.POLICIES``; for ``single``
    and ``full`` it only fills the planner's slot); GR on (``refinement``) or off; GR's model ``library``
    ("known": the scenes' own instances, the paper's; "category": the training instances only); an oracle
    row's ``scored_by`` (``Label``: greedy, or its ``policy``'s rollouts to T) and whether its ``policy`` makes
    its last move (``policy_last``: the oracle does not pick the last view by the truth)."""

    label: str
    kind: Kind
    policy: str = "vis_occl_hist"
    refinement: bool = True
    library: str = "known"
    scored_by: Label = Label.greedy
    policy_last: bool = False

    def settings(self, base: ActiveConfig, moves: int) -> ActiveConfig:
        """``base`` with this row's policy, GR and library; one move for ``single``, T otherwise."""
        episode = dataclasses.replace(base.episode, policy=self.policy, refinement=self.refinement,
                                      moves=1 if self.kind is Kind.SINGLE else moves, off_grid=False)
        return dataclasses.replace(base, episode=episode, refine=dataclasses.replace(base.refine, library=self.library))

    def episode(self, base: ActiveConfig, moves: int, classifier: pointnet.Classifier, object_set: ObjectSet,
                intrinsics: Intrinsics, table_height: float, scene_split: str = "test") -> active.Episode:
        """This row's episode (``settings``) with ``classifier`` (GR's ``refine.yaw_source=auto`` takes the
        learned yaw with a yaw head, else evenly spaced hypotheses: ``RefineConfig.resolve``)."""
        return setup.make_episode(self.settings(base, moves), object_set, intrinsics, table_height, classifier,
                                  scene_split)


def _pair(name: str, label: str, kind: Kind, policy: str = "vis_occl_hist") -> dict[str, Row]:
    return {name: Row(label, kind, policy, refinement=False), f"{name}_gr": Row(f"{label}GR", kind, policy)}


# The paper's twelve rows in its order, then the rows beyond it.
ROWS: dict[str, Row] = {
    **_pair("single", "PointNetSingle", Kind.SINGLE),
    **_pair("full", "PointNetFull", Kind.FULL),
    **_pair("random", "Random", Kind.POLICY, "random"),
    **_pair("vis_no_occl", "VisNoOccl", Kind.POLICY, "vis_no_occl"),
    **_pair("vis_occl", "VisOccl", Kind.POLICY, "vis_occl"),
    **_pair("vis_occl_hist", "VisOcclHist", Kind.POLICY, "vis_occl_hist"),
    "vis_occl_hist_unc_gr": Row("VisOcclHistUncGR", Kind.POLICY, "vis_occl_hist_unc"),
    "info_gain_gr": Row("InfoGainGR", Kind.POLICY, "info_gain"),
    "continuous_gr": Row("ContinuousGR", Kind.POLICY, "continuous"),
    # The learned policy (``nbv.learned.weights``: ``jaxcls train-policy``'s ``policy.msgpack``).
    "learned_gr": Row("LearnedGR", Kind.POLICY, "learned"),
    "vis_occl_hist_gr_category": Row("VisOcclHistGR (category models)", Kind.POLICY, "vis_occl_hist",
                                     library="category"),
    "oracle_gr": Row("OracleGR", Kind.ORACLE),
    # The oracle one step ahead of InfoGain: each candidate scored by its F1 at T with InfoGain making the moves
    # after it (``Label.rollout``; what ``train-policy labels=rollout`` imitates).
    "oracle_rollout_gr": Row("OracleRolloutGR", Kind.ORACLE, "info_gain", scored_by=Label.rollout),
    # The same with InfoGain making the last move: at the last decision a rollout label is the true F1 right after
    # the move, and picking by it takes the view after which the classifier happens to be right, which no policy
    # without the truth can copy (RESULTS.md, "The learned view policy"). A bound a policy can aim for.
    "oracle_rollout_policy_last_gr": Row("OracleRolloutGR (InfoGain last)", Kind.ORACLE, "info_gain",
                                         scored_by=Label.rollout, policy_last=True),
}
PAPER_ROWS = tuple(ROWS)[:12]


def row(name: str, key: str = "rows") -> Row:
    """The row registered as ``name`` (ValueError naming ``key`` and the choices)."""
    if name not in ROWS:
        raise ValueError(f"{key}: unknown row {name!r}; choose from {list(ROWS)}")
    return ROWS[name]


def start_views(seed: int, scene: int, runs: int, num_views: int) -> np.ndarray:
    """[runs] i64 distinct random start views of a scene's runs (the same for every row: rows are paired)."""
    rng = np.random.default_rng([seed, scene])
    return rng.choice(num_views, size=runs, replace=runs > num_views)


def run_keys(seed: int, scene: int, runs: int) -> jax.Array:
    """[runs] the episodes' keys (the same for every row)."""
    base = jax.random.fold_in(jax.random.PRNGKey(seed), scene)
    return jax.vmap(lambda r: jax.random.fold_in(base, r))(jnp.arange(runs))


def _one_rollout(episode: active.Episode, depth: jax.Array, T_wc: jax.Array, start: jax.Array, key: jax.Array
                 ) -> active.Trace:
    return active.rollout(episode, active.reset(episode, T_wc, start, key), depth, T_wc)[1]


# Runs of one scene: depth [V, H, W] and T_wc [V, 4, 4] shared, starts [R] and keys [R] batched.
_rollouts = jax.jit(jax.vmap(_one_rollout, in_axes=(None, None, None, 0, 0)))


def rollouts(episode: active.Episode, depth: jax.Array, T_wc: jax.Array, starts: np.ndarray, keys: jax.Array
             ) -> active.Trace:
    """The runs of one scene from ``starts: [R]`` with ``keys: [R]``, one ``vmap``ped ``jit``: a ``Trace``
    with [R, T, ...] leaves. depth: [V, H, W] m; T_wc: [V, 4, 4] every viewpoint's frame."""
    return _rollouts(episode, jnp.asarray(depth, jnp.float32), jnp.asarray(T_wc, jnp.float32),
                     jnp.asarray(starts, jnp.int32), keys)


@functools.partial(jax.jit, static_argnames="passes")
def _all_views(episode: active.Episode, depth: jax.Array, T_wc: jax.Array, key: jax.Array, passes: int
               ) -> tuple[active.Trace, jax.Array]:
    V = T_wc.shape[0]
    state = active.reset(episode, T_wc, 0, key)
    order = jnp.concatenate([jnp.arange(1, V), jnp.zeros(1, jnp.int32)]).astype(jnp.int32)
    obs, poses = observation.reconstruct_views(episode.spec, state.observation, depth[1:], T_wc[1:], passes)
    # Every view is a visited one, its camera among those GR's visibility-aware rho sees the models from
    # (the path and cameras span all V views here, not the episode's T moves; the last joins with its move).
    state = state.replace(observation=obs, path=order, cameras=jnp.concatenate([poses[:, :3, 3], T_wc[:1, :3, 3]]),
                          views=state.views.replace(visited=jnp.ones(V, bool).at[0].set(False)))
    state = active.step(episode, state, depth[0], T_wc[0])
    poses = jnp.concatenate([poses, state.observation.tracking.pose[None]])
    return jax.tree.map(lambda x: x[None], active.trace(state, jnp.asarray(0, jnp.int32))), poses


def all_views(episode: active.Episode, depth: jax.Array, T_wc: jax.Array, key: jax.Array, passes: int = 2
              ) -> tuple[active.Trace, jax.Array]:
    """PointNetFull: views 1..V-1 fused, then a move on view 0 (fused, segmented, classified, refined, GR's
    rho seeing the models from all V cameras): a ``Trace`` of one move ([1, ...] leaves), and the poses
    [V, 4, 4] every view was fused at (tracked, or as given with tracking off), views 1..V-1 then 0.

    With tracking and its hand-eye estimate on, views 1..V-1 are fused ``passes`` times, each pass from an
    empty volume with the hand-eye estimate the previous one ended with (``observation.reconstruct_views``:
    the offline upper bound has every view before it fuses the first); with one pass they are tracked as an
    episode tracks its frames."""
    return _all_views(episode, jnp.asarray(depth, jnp.float32), jnp.asarray(T_wc, jnp.float32), key, passes)


def _moves_to(episode: active.Episode, state: active.EpisodeState, depth: jax.Array, T_wc: jax.Array,
              scene: jax.Array, views: jax.Array) -> tuple[active.EpisodeState, active.Trace]:
    """The move to each of ``views: [C]`` of ``scene``'s frames (depth [S, V, H, W], T_wc [S, V, 4, 4]) from one
    ``state`` (vmapped): [C] states and their traces."""
    def go(view):
        new = active.step(episode, state.replace(next_view=view), depth[scene, view], T_wc[scene, view])
        return new, active.trace(new, view)

    return jax.vmap(go)(views)


# The runs' first states: T_wc [R, V, 4, 4] (each run's scene's), starts [R], keys [R] -> [R] states.
_resets = jax.jit(jax.vmap(active.reset, in_axes=(None, 0, 0, 0)))
# Runs [R], each from its own state to its own candidates of its scene: views [R, C] -> [R, C] states, traces.
_runs_moves_to = jax.jit(jax.vmap(_moves_to, in_axes=(None, 0, None, None, 0, 0)))
# Each run's state after the candidate it keeps: [R, C] states, pick [R] -> [R] states (one program, not a gather
# of each leaf; its states are like the resets' to the next move's program: no second signature).
_picked = jax.jit(lambda states, pick: jax.tree.map(lambda x: x[jnp.arange(pick.shape[0]), pick], states))


@jax.jit
def _continued(episode: active.Episode, states: active.EpisodeState, depth: jax.Array, T_wc: jax.Array,
               scene: jax.Array, remaining: jax.Array) -> active.Trace:
    """[R, C] states (runs [R] of scenes ``scene`` [R], frames depth [S, V, H, W], T_wc [S, V, 4, 4]) each taken
    ``remaining`` ([] i32, traced: one program for every move) more moves by the episode's own policy; the
    ``Trace`` of each one's last move ([R, C] leaves)."""
    def run(state, s):
        def move(_, st):
            return active.step(episode, st, depth[s, st.next_view], T_wc[s, st.next_view])

        final = jax.lax.fori_loop(0, remaining, move, state)
        return active.trace(final, final.views.current)

    return jax.vmap(jax.vmap(run, in_axes=(0, None)))(states, scene)


@jax.jit
def _runs_candidates(episode: active.Episode, views: nbv.Views) -> tuple[jax.Array, jax.Array]:
    """Each run's candidates (``nbv.candidates``): index, ok [R, C]; C fixed (``max_candidates``)."""
    return jax.vmap(lambda v: nbv.candidates(v, episode.nbv_config))(views)


def oracle_rollouts(episode: active.Episode, depth: np.ndarray, T_wc: np.ndarray, starts: np.ndarray,
                    keys: jax.Array, truth: scoring.Truth | Sequence[scoring.Truth],
                    scene: np.ndarray | None = None, kernels: batched.Kernels = batched.Kernels.fixed,
                    tap: Callable[..., np.ndarray] | None = None, label: Label = Label.greedy,
                    policy_last: bool = False) -> active.Trace:
    """The oracle NBV for the runs ``starts: [R]`` (keys [R]): the first move from each start; then at each move
    every candidate of every run (``nbv.candidates`` within the radius, unvisited ones first) is fused,
    segmented, classified and refined in one vmapped call, and each run keeps the one whose refined labels score
    the best true F1 of the target objects (ties: the nearer candidate). A ``Trace`` with [R, T, ...] leaves.
    With ``label=Label.rollout`` a candidate's F1 is the one at T after the episode's own policy takes the moves
    left from there (``_continued``, one more program); the runs still keep the candidate itself. With
    ``policy_last`` the last decision is the episode's own policy's (its ``next_view``), not the best label's.

    One scene: depth [V, H, W] m, T_wc [V, 4, 4], ``truth`` its ``Truth``. Several scenes in one call: depth
    [S, V, H, W], T_wc [S, V, 4, 4], ``scene: [R]`` each run's scene and ``truth`` a ``Truth`` per run.

    Every move is one program of one shape ([R, C] moves; the first one's C columns all go to the start): traced
    once (kept on disk with the compilation cache on, ``compile_cache.exported``), with ``kernels`` as the
    batched rows' (``batched.Kernels``: ``fixed`` picks the same GPU kernels on every compilation, so that a
    process that compiles it again gives the same records).

    ``tap(states, index, ok, allowed, f1, pick) -> pick``, where given, sees every decision after the first move:
    the runs' states before it ([R] leaves), their candidates (index, ok, allowed [R, C]: ``allowed`` the ones the
    oracle ranks), each candidate's true F1 after the move ([R, C], -1 where not allowed) and the oracle's pick
    [R]; the runs go where it returns (e.g. a learned policy's choice, labelled by the oracle's F1: DAgger)."""
    depth, T_wc = jnp.asarray(depth, jnp.float32), jnp.asarray(T_wc, jnp.float32)
    starts = np.asarray(starts, np.int64)
    R, num_classes = len(starts), len(episode.spec.classifier.classes)
    if scene is None:
        depth, T_wc, scene, truths = depth[None], T_wc[None], np.zeros(R, np.int32), [truth] * R
    else:
        scene, truths = np.asarray(scene, np.int32), list(truth)
        if scene.shape != (R,) or len(truths) != R or depth.ndim != 4 or T_wc.ndim != 4:
            raise ValueError(f"oracle_rollouts: several scenes need depth [S, V, H, W], T_wc [S, V, 4, 4], scene [R] "
                             f"and a truth per run; got {depth.shape}, {T_wc.shape}, {scene.shape}, {len(truths)} "
                             f"truths for {R} runs")
    runs, device = np.arange(R), next(iter(depth.devices()))
    args = _oracle_first_move(episode, depth, T_wc, scene, starts, keys, device)
    moves_to = compile_cache.exported(_runs_moves_to, args, "oracle_moves", batched.KERNEL_OPTIONS[kernels])
    episode, states, depth, T_wc, at, _ = args
    states, traces = moves_to(*args)
    traces = jax.device_get(traces)  # [R, C] traces on the host once a move: scored, and the picks kept
    pick = np.zeros(R, np.int64)
    kept = []
    for _ in range(episode.config.moves):
        states = _picked(states, jnp.asarray(pick, jnp.int32))
        kept.append(jax.tree.map(lambda x, p=pick: x[runs, p], traces))
        if len(kept) == episode.config.moves:
            break
        index, ok = map(np.asarray, _runs_candidates(episode, states.views))  # [R, C]
        fresh = ok & ~np.take_along_axis(np.asarray(states.views.visited), index, axis=1)
        first = np.arange(index.shape[1]) == 0
        allowed = np.where(fresh.any(1, keepdims=True), fresh, np.where(ok.any(1, keepdims=True), ok, first))
        before, choices = states, (index, ok, allowed)
        index = jax.device_put(jnp.asarray(index, jnp.int32), device)
        states, traces = moves_to(episode, states, depth, T_wc, at, index)
        left = episode.config.moves - len(kept) - 1  # (the moves after the candidate's)
        scored = (_continued(episode, states, depth, T_wc, at, jnp.int32(left))
                  if Label(label) is Label.rollout and left > 0 else traces)
        traces, scored = jax.device_get((traces, scored))
        centroid, valid, refined = scored.centroid, scored.refinement.valid, scored.refinement.refined
        f1 = np.stack([scoring.candidate_f1(truths[r], centroid[r], valid[r], refined[r], num_classes) for r in runs])
        f1 = np.where(allowed, f1, -1.0)
        pick = np.argmax(f1, axis=1)
        if policy_last and left == 0:  # (the policy's view: a candidate, unless the policy goes off the candidates)
            ours = choices[0] == np.asarray(before.next_view)[:, None]
            if not np.all(ours.any(1)):
                raise ValueError(f"oracle_rollouts: the policy's last views {np.asarray(before.next_view).tolist()} "
                                 "are not all among the runs' candidates")
            pick = np.argmax(ours, axis=1)
        if tap is not None:
            pick = np.asarray(tap(before, *choices, f1, pick), np.int64)
            if pick.shape != (R,) or not np.all(np.take_along_axis(allowed, pick[:, None], axis=1)):
                raise ValueError(f"oracle_rollouts: tap must return [R] = [{R}] picks among the allowed candidates, "
                                 f"got {pick.tolist()}")
    return jax.tree.map(lambda *xs: np.stack(xs, axis=1), *kept)


def _oracle_first_move(episode: active.Episode, depth: jax.Array | jax.ShapeDtypeStruct, T_wc: jax.Array,
                       scene: np.ndarray, starts: np.ndarray, keys: jax.Array, device: jax.Device) -> tuple:
    """The oracle's move program's arguments for its first move (every candidate column to the start): episode,
    the runs' reset states, depth, T_wc, each run's scene, the views [R, C]. Every input committed to ``device``,
    the frames': the program sees one signature on every move (its own outputs, the next move's states, are
    committed); a ``jax.ShapeDtypeStruct`` ``depth`` (frames not yet rendered) gets that device's sharding."""
    at, episode, T_wc = jax.device_put((jnp.asarray(scene), episode, T_wc), device)
    states = jax.device_put(_resets(episode, T_wc[at], jnp.asarray(starts, jnp.int32), keys), device)
    C = _runs_candidates(episode, states.views)[0].shape[1]
    to_start = jax.device_put(jnp.asarray(np.repeat(np.asarray(starts)[:, None], C, axis=1), jnp.int32), device)
    if isinstance(depth, jax.ShapeDtypeStruct):
        depth = jax.ShapeDtypeStruct(depth.shape, jnp.float32, sharding=to_start.sharding)
    return episode, states, depth, T_wc, at, to_start


def prepare_oracle(episode: active.Episode, frames: tuple[int, int, int, int], runs: int,
                   kernels: batched.Kernels = batched.Kernels.fixed) -> None:
    """Read and compile (with the compilation cache on: load) the program ``oracle_rollouts`` runs for
    ``episode`` over several scenes' frames of shape ``frames`` = (S, V, H, W) on the default device, ``runs``
    runs a call, before the frames exist: e.g. on a background thread (``compile_cache.ahead``) while the host
    waits for other episodes. Without the cache nothing is done here (the first call compiles)."""
    if not compile_cache.enabled():
        return
    S, V = frames[0], frames[1]
    device = next(iter(jnp.zeros((), jnp.float32).devices()))
    T_wc = np.broadcast_to(np.eye(4, dtype=np.float32), (S, V, 4, 4))
    key = jax.random.PRNGKey(0)
    args = _oracle_first_move(episode, jax.ShapeDtypeStruct(tuple(frames), jnp.float32), jnp.asarray(T_wc),
                              np.zeros(runs, np.int32), np.zeros(runs, np.int64),
                              jnp.broadcast_to(key, (runs, *key.shape)), device)
    compile_cache.exported(_runs_moves_to, args, "oracle_moves", batched.KERNEL_OPTIONS[kernels])


def episode_record(trace: active.Trace, truth: scoring.Truth, **keys: Any) -> dict[str, Any]:
    """The JSON record of one episode (``trace``: [T, ...] leaves of one run): ``keys`` (classifier, row,
    scene, run, start, ...), the views fused (``path``), the target objects' true classes (``true``: [K])
    and their prior and refined labels after every move (``prior``, ``refined``: [T][K]; -1 = no segment
    matched the object); each frame's tracking status (``tracking.Status``) and the hand-eye estimate Y
    after it (``hand_eye``: [T][6], its SE(3) log, translation m then rotation rad); the refined classes of the
    phantom segments after every move (``phantom``: [T][p], live segments that matched no object, target or
    clutter), the live segments' count (``segments``: [T]) and the scene's objects' (``objects``). A move the
    episode did not make (it had stopped) repeats the last labels. ``episode_records`` does a batch at once."""
    return episode_records(jax.tree.map(lambda x: np.asarray(x)[None], trace), [truth], [keys])[0]


@jax.jit
def _se3_log(matrices: jax.Array) -> jax.Array:
    """[..., 6] the SE(3) log of [..., 4, 4] transforms (jaxlie)."""
    return jaxlie.SE3.from_matrix(matrices).log()


def episode_records(traces: active.Trace, truths: Sequence[scoring.Truth], keys: Sequence[dict[str, Any]]
                    ) -> list[dict[str, Any]]:
    """``episode_record`` of E episodes at once (``traces``: [E, T, ...] host leaves; ``truths`` and ``keys``:
    one per episode): the hand-eye logs in one call on the host's CPU, one assignment per move made."""
    prior, refined = np.asarray(traces.refinement.prior), np.asarray(traces.refinement.refined)
    centroid, valid = np.asarray(traces.centroid), np.asarray(traces.refinement.valid)
    done, views, status = np.asarray(traces.done), np.asarray(traces.view), np.asarray(traces.tracking)
    E, T = done.shape
    if not (len(truths) == len(keys) == E):
        raise ValueError(f"episode_records: {E} episodes, {len(truths)} truths and {len(keys)} key sets")
    # On the host's CPU where JAX has one (never queued behind the batch an accelerator is running).
    on_host = jax.device_put(np.asarray(traces.hand_eye, np.float32), devices.host_cpu())
    hand_eye = np.round(np.asarray(_se3_log(on_host), np.float64), 6)  # [E, T, 6]
    names = {s.value: s.name.lower() for s in tracking.Status}
    # Each scene's episodes matched to its objects together (one truth, every move at once); a move after the
    # episode stopped keeps the labels of the move before.
    labels: list[np.ndarray | None] = [None] * E  # [T, 2, targets] each
    phantom: list[np.ndarray | None] = [None] * E  # [T, N] each: a phantom segment's refined class, else -1
    segments = np.asarray(valid).sum(axis=-1)  # [E, T] live segments after each move
    same_truth: dict[int, list[int]] = {}
    for e, truth in enumerate(truths):
        same_truth.setdefault(id(truth), []).append(e)
    for members in same_truth.values():
        truth, idx = truths[members[0]], np.asarray(members)
        N = centroid.shape[2]
        match = metrics.match_objects_batched(centroid[idx].reshape(-1, N, 3), valid[idx].reshape(-1, N),
                                              truth.centroid).reshape(len(idx), T, -1)  # [n, T, K]
        both = np.stack([prior[idx], refined[idx]], axis=2)  # [n, T, 2, N]
        picked = np.take_along_axis(both, np.maximum(match, 0)[:, :, None, :], axis=-1)
        picked = np.where(match[:, :, None, :] >= 0, picked, -1)[..., truth.target]  # [n, T, 2, targets]
        # Phantoms: live segments that matched no object (target or clutter), with their refined class.
        matched = np.zeros(valid[idx].shape, bool)  # [n, T, N]
        ii, tt, kk = np.nonzero(match >= 0)
        matched[ii, tt, match[ii, tt, kk]] = True
        ghosts = np.where(valid[idx] & ~matched, refined[idx], -1)  # [n, T, N]
        for t in range(1, T):
            picked[:, t] = np.where(done[idx, t][:, None, None], picked[:, t - 1], picked[:, t])
            ghosts[:, t] = np.where(done[idx, t][:, None], ghosts[:, t - 1], ghosts[:, t])
        for i, e in enumerate(members):
            labels[e], phantom[e] = picked[i], ghosts[i]
    for t in range(1, T):
        segments[:, t] = np.where(done[:, t], segments[:, t - 1], segments[:, t])
    phantom_lists = np.stack(phantom).tolist()  # [E][T][N] (one conversion; filtered below)
    segment_lists = segments.tolist()
    records = []
    for e, (truth, key) in enumerate(zip(truths, keys, strict=True)):
        made = ~done[e]
        records.append({**key, "path": views[e][made].tolist(), "true": truth.label[truth.target].tolist(),
                        "prior": labels[e][:, 0].tolist(), "refined": labels[e][:, 1].tolist(),
                        "tracking": [names[s] for s in status[e][made]], "hand_eye": hand_eye[e][made].tolist(),
                        "phantom": [[c for c in row if c >= 0] for row in phantom_lists[e]],
                        "segments": segment_lists[e], "objects": len(truth.label)})
    return records


@dataclasses.dataclass(frozen=True, eq=False)
class SceneLabels:
    """A row's target labels scene by scene, after every move at once (``scene_labels``): ``true [n]`` and
    ``predicted [T, n]`` (an episode of fewer moves repeats its last), the records' scenes ascending, each
    scene's runs in the records' order; ``cuts``: where each scene's labels begin (after the first)."""

    true: np.ndarray
    predicted: np.ndarray
    cuts: np.ndarray

    def at(self, move: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """[(true [n_s], predicted [n_s])] per scene after ``move`` (1-based; past an episode's end, its last)."""
        if not len(self.predicted):
            return []
        predicted = self.predicted[min(move, len(self.predicted)) - 1]
        return list(zip(np.split(self.true, self.cuts), np.split(predicted, self.cuts), strict=True))


def scene_labels(records: Sequence[dict[str, Any]], label: str = "refined", phantoms: bool = False
                 ) -> SceneLabels:
    """The ``label`` labels of ``records`` (one row's) per scene, pooling each scene's runs, for every move
    (``SceneLabels.at(move)``: ``per_scene``'s answer). Where every record has as many moves and targets, one
    NumPy conversion of all; else a move at a time. ``phantoms``: each record's phantom segments too (its
    ``phantom`` classes as detections of no object, true -1: false positives; ``label`` must be "refined"),
    padded to the row's most with empty slots (-1, -1), which count nowhere."""
    if phantoms and (label != "refined" or any("phantom" not in r for r in records)):
        raise ValueError("scene_labels: phantoms need the refined labels of records that keep their phantom "
                         "segments (stored since 2026-11-26)")
    if not records:
        return SceneLabels(np.zeros(0, np.int64), np.zeros((0, 0), np.int64), np.zeros(0, np.int64))
    scene = np.array([int(r["scene"]) for r in records], np.int64)
    order = np.argsort(scene, kind="stable")  # scenes ascending, each scene's runs in the records' order
    ordered = [records[i] for i in order]
    most = max((len(x) for r in ordered for x in r["phantom"]), default=0) if phantoms else 0
    true = [r["true"] for r in ordered]
    sizes = np.array([len(t) for t in true], np.int64)
    moves = np.array([len(r[label]) for r in ordered], np.int64)
    bad = ValueError(f"scene_labels: a record's {label!r} labels and its true labels differ in length")
    T = int(moves.max())
    if (moves == moves[0]).all() and (sizes == sizes[0]).all():
        try:
            labels = np.asarray([r[label] for r in ordered], np.int64)  # [E, T, K]
        except ValueError:  # (ragged: some move's labels are not K long)
            raise bad from None
        if labels.shape != (len(ordered), T, sizes[0]):
            raise bad
        true_labels = np.asarray(true, np.int64).reshape(len(ordered), sizes[0])
        if most:  # the phantoms after the targets, padded with empty slots
            ghost = np.full((len(ordered), T, most), -1, np.int64)
            for e, r in enumerate(ordered):
                for t, x in enumerate(r["phantom"]):
                    if x:
                        ghost[e, t, :len(x)] = x
            labels = np.concatenate([labels, ghost], axis=2)
            true_labels = np.pad(true_labels, ((0, 0), (0, most)), constant_values=-1)
            sizes = sizes + most
        predicted = labels.transpose(1, 0, 2).reshape(T, -1)
        true_flat = true_labels.ravel()
    else:
        if most:
            ordered = [{**r, "true": [*r["true"], *[-1] * most],
                        label: [[*labels, *x, *[-1] * (most - len(x))]
                                for labels, x in zip(r[label], r["phantom"], strict=True)]} for r in ordered]
            true, sizes = [r["true"] for r in ordered], sizes + most
        n = int(sizes.sum())
        if any(len(labels) != k for r, k in zip(ordered, sizes, strict=True) for labels in r[label]):
            raise bad
        predicted = np.stack([np.fromiter(itertools.chain.from_iterable(r[label][min(t, len(r[label]) - 1)]
                                                                        for r in ordered), np.int64, n)
                              for t in range(T)])
        true_flat = np.fromiter(itertools.chain.from_iterable(true), np.int64, n)
    starts = np.flatnonzero(np.diff(scene[order])) + 1  # the records where a new scene begins
    return SceneLabels(true=true_flat, predicted=predicted, cuts=np.cumsum(sizes)[starts - 1])


def per_scene(records: Sequence[dict[str, Any]], move: int, label: str = "refined"
              ) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(true [n_s], predicted [n_s])] per scene (sorted by scene), pooling a row's runs of each scene, with
    the labels after ``move`` (1-based; an episode of fewer moves, PointNetSingle or PointNetFull, counts
    with its last). For several moves of one row, ``scene_labels`` once."""
    return scene_labels(records, label).at(move)


def moves_to_correct(records: Sequence[dict[str, Any]], label: str = "refined", labels: SceneLabels | None = None
                     ) -> tuple[float, float]:
    """(mean moves until a target's label turns right and stays right, over the targets that end right;
    the share of targets right after the last move). ``labels``: ``scene_labels(records, label)`` where the
    caller has them (an episode of fewer moves repeats its last labels there, which changes neither)."""
    labels = labels or scene_labels(records, label)
    if not labels.predicted.size:
        return float("nan"), 0.0
    correct = labels.predicted == labels.true[None]  # [T, n]
    wrong = ~correct
    last_wrong = len(correct) - 1 - np.argmax(wrong[::-1], axis=0)  # (where any move was wrong)
    moves = np.where(wrong.any(axis=0), last_wrong + 2, 1)[correct[-1]]
    return (float(moves.mean()) if moves.size else float("nan")), float(correct[-1].mean())


__all__ = ["PAPER_ROWS", "ROWS", "Kind", "Label", "Row", "SceneLabels", "all_views", "episode_record",
           "episode_records", "moves_to_correct", "oracle_rollouts", "per_scene", "prepare_oracle", "rollouts", "row",
           "run_keys", "scene_labels", "start_views"]
