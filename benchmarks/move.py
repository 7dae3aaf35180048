"""One move of the active loop on the CPU: our JAX move (``active.timed_step``, stage by stage, and
``active.step_jit``, one jit) against a peer composition of the libraries a practitioner would reach for,
on the same frames and the same episode states, interleaved in one process.

    python benchmarks/move.py [--scenes 3] [--moves 5] [--rounds 3] [--allocator retain] [--out BENCHMARKS.md]

Scenes: builtin 5-object worlds (``make_world``, ``mujoco`` backend, Kinect v1 640x480, seeds 0..n-1), the
episode of ``setup.ActiveConfig()`` with ``--moves`` moves from viewpoint 0. A warm-up episode per scene
fixes the path, renders its frames (rendering is never timed), compiles, and keeps the state before every
move. Each round then times every move after the first of every scene, A and B in turn (the order flips
from move to move), each from the same stored state and frame:

- ours, stage by stage: ``active.timed_step`` (each module its own jit, waited for: the per-module times);
- ours, fused: ``active.step_jit`` (one XLA program per move; total only);
- peer: reconstruction as ours does it, the camera tracked first (``active.timed_step``'s reconstruction
  registers the frame to the fused model before fusing it): the frame registered to the peer's current
  surface (its last ``extract_point_cloud``, table points dropped, with normals) by Open3D's point-to-plane
  ``registration_icp`` from the reported pose (``jaxcls.experiments.peers.Open3DTracker``, as in
  ``benchmarks/tracking.py``: the frame's foreground points at every 2nd pixel, 0.02 m gate, at most 20
  iterations; the episode's first frame, with no surface yet, stays at the reported pose), then integrated at
  the registered pose into Open3D's ``UniformTSDFVolume`` (the episode's 0.6 m / 128^3 cube, 4-voxel
  truncation; one volume per episode) and ``extract_point_cloud``, table points dropped, padded to the
  episode's surface size; segmentation with the reference path (``perception.segment.segment``: scikit-learn
  DBSCAN, the footprint watershed, K-means); classification with the same PointNet (``pointnet.classify``); GR
  with Open3D's point-to-plane ``registration_icp`` for every (segment, top-3 class, model of the class, yaw)
  one after another (``peers.open3d_refine``, as in ``benchmarks/refine.py``: 30 iterations, rho from
  KD-trees), on the segments' points strided to the episode's ``icp.points``, as many even yaws as our learned
  ones; NBV: the NumPy/SciPy count of the paper (``peers.numpy_paper``, as in ``benchmarks/nbv.py``) over the
  move's candidates within the radius, with our state's aligned cuboids, at the planner's 0.25 scale, then
  Eq. 6-8 in NumPy.

The process keeps freed memory for reuse (``jaxcls.allocator.retain_freed_memory``, as ``jaxcls``'s commands
do) unless ``--allocator default``; the setting is process-wide, so ours and the peer always share it.

Per-module columns are medians over the timed moves; "median ms per move" is the median of the moves'
wall-clock totals; "range over rounds" spans the rounds' medians.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import statistics
import sys
import time

import jax
import numpy as np

from jaxcls import allocator, report
from jaxcls.episode import active, setup, sources
from jaxcls.experiments.peers import HostPose, HostTarget, Open3DTracker, numpy_paper, open3d_refine
from jaxcls.perception import icp, pointnet, pose, refine, segment
from jaxcls.planning import nbv, visibility
from jaxcls.world import WorldConfig, make_world
from jaxcls.world.objects import ObjectSet

START = 0  # the episodes' first viewpoint (``jaxcls run``'s default)
# The paper's averaged processing time between consecutive moves (Sec. 5, an Alienware Aurora desktop, i7), s.
PAPER = {"reconstruction": 0.12, "segmentation": 0.06, "refinement": 0.88, "planning": 0.19}
COLUMNS = {"reconstruction": "reconstruction", "segmentation": "segmentation", "classification": "classification",
           "refinement": "GR (Eq. 2-4)", "planning": "NBV (Eq. 5-8)"}


@dataclasses.dataclass
class Scene:
    """One scene's fixed episode: frames[t] is move t's (depth, T_wc); states[t] the state before it
    (states[moves] after the last)."""

    episode: active.Episode
    object_set: ObjectSet
    frames: list[tuple[np.ndarray, np.ndarray]]
    states: list[active.EpisodeState]


def _scene(seed: int, moves: int, classifier: pointnet.Classifier) -> Scene:
    world = make_world(WorldConfig(backend="mujoco"), seed=seed)
    settings = setup.ActiveConfig(episode=active.EpisodeConfig(moves=moves))
    episode = setup.make_episode(settings, world.object_set, world.intrinsics, world.table_height, classifier)
    source = sources.Rendered(world, jax.random.PRNGKey(seed))
    state = active.reset(episode, source.viewpoints, START, jax.random.PRNGKey(0))
    frames, states = [], [state]
    while not bool(state.done):
        depth, T_wc = source.frame(int(state.next_view))
        frames.append((np.asarray(depth, np.float32), np.asarray(T_wc, np.float32)))
        state, _ = active.timed_step(episode, state, *frames[-1])
        states.append(state)
    return Scene(episode, world.object_set, frames, states)


class Peer:
    """The peer composition of a move (Open3D, scikit-learn, the same PointNet, Open3D ICP, NumPy)."""

    def __init__(self, episode: active.Episode, models, same_models: bool = False):
        import open3d as o3d

        self.same_models = same_models
        self.height = np.array([float(np.asarray(m.surface_points)[:, 2].max()) for m in models])
        self.o3d, self.episode, self.spec = o3d, episode, episode.spec
        intr = self.spec.intrinsics
        self.K = o3d.camera.PinholeCameraIntrinsic(intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy)
        self.color = o3d.geometry.Image(np.zeros((intr.height, intr.width, 3), np.uint8))
        config = episode.refine_config
        self.targets = [HostTarget(*(np.asarray(a) for a in icp.model_target(m, config.icp).samples()))
                        for m in models]
        x = np.random.default_rng(0).normal(size=(64, 3)).astype(np.float32)
        np.testing.assert_allclose(HostPose.initial_poses(x, x[:, 0] > 0, x[0], 0.1, HostPose.even_yaws(3)),
                                   pose.initial_poses(x, x[:, 0] > 0, x[0], 0.1, pose.even_yaws(3)), atol=1e-5)
        # Every model is a "class" of its own to ``open3d_refine``: each segment's top-k classes' models are the
        # top k x J of the models' scores (each model scored as its class), so it registers all of them.
        classes = episode.spec.classifier.classes
        self.model_class = np.array([classes.index(m.class_name) for m in models])
        per_class = np.bincount(self.model_class, minlength=len(classes))
        if per_class.min() != per_class.max():
            raise ValueError(f"move: the peer needs as many models of every class, got {per_class.tolist()}")
        self.config = dataclasses.replace(config, top_k=config.top_k * int(per_class[0]))
        self.small = visibility.scaled(self.spec.intrinsics, episode.nbv_config.visibility.scale)
        self.volume = None
        foreground = self.spec.config.foreground
        self.tracker = Open3DTracker(intr, self.spec.floor, foreground.max_depth)
        self.surface: tuple[np.ndarray, np.ndarray] | None = None  # the last extracted surface: points, normals
        self.tracking_ms: list[float] = []  # the frame-to-model registrations' times (within reconstruction)

    def reset(self, episode: active.Episode) -> None:
        """A new episode (its table, volume and planner settings): an empty volume."""
        if episode.spec.intrinsics != self.spec.intrinsics or episode.library.names != self.episode.library.names:
            raise ValueError("move: every scene's episode must share the camera and the model library")
        self.episode, self.spec = episode, episode.spec
        v = self.spec.config.volume
        integration = self.o3d.pipelines.integration
        # Open3D's origin is the cube's corner (benchmarks/tsdf.py).
        self.volume = integration.UniformTSDFVolume(v.size, v.resolution, v.truncation_voxels * v.voxel_size,
                                                    integration.TSDFVolumeColorType.NoColor,
                                                    np.asarray(self.spec.roi_center, float) - v.size / 2)
        self.tracker.floor = self.spec.floor  # this episode's table
        self.surface = None

    def integrate(self, depth: np.ndarray, T_wc: np.ndarray) -> None:
        rgbd = self.o3d.geometry.RGBDImage.create_from_color_and_depth(
            self.color, self.o3d.geometry.Image(depth), depth_scale=1.0,
            depth_trunc=self.spec.config.foreground.max_depth, convert_rgb_to_intensity=False)
        self.volume.integrate(rgbd, self.K, np.linalg.inv(np.asarray(T_wc, np.float64)))

    def reconstruct(self, depth: np.ndarray, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The frame registered to the surface so far (Open3D ICP from the reported ``T_wc``; the first frame of
        the episode at ``T_wc``), integrated at the registered pose, the surface extracted, table points dropped,
        padded to [P]."""
        if self.surface is not None:
            start = time.perf_counter()
            T_wc = self.tracker.register(depth, T_wc, *self.surface)
            self.tracking_ms.append(1e3 * (time.perf_counter() - start))
        self.integrate(depth, T_wc)
        cloud = self.volume.extract_point_cloud()
        points, normals = np.asarray(cloud.points, np.float32), np.asarray(cloud.normals, np.float32)
        keep = points[:, 2] > self.spec.floor
        points, normals = points[keep], normals[keep]
        P = self.spec.config.shapes.surface_points
        if len(points) > P:  # an evenly spread subset, as ``tsdf.extract_surface``
            pick = np.linspace(0, len(points) - 1, P).round().astype(int)
            points, normals = points[pick], normals[pick]
        self.surface = (points, normals)
        mask = np.zeros(P, bool)
        mask[:len(points)] = True
        pad = ((0, P - len(points)), (0, 0))
        return np.pad(points, pad), np.pad(normals, pad), mask

    def refine(self, points: np.ndarray, mask: np.ndarray, probs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(refined class [N], pose [N, 4, 4]) by Open3D ICP over every top-k class's models and yaws (with
        ``same_models``: only the models ours registers, those of each class nearest the segment in height)."""
        count = self.config.icp.points
        N = len(points)
        strided_points, strided_mask = np.zeros((N, count, 3), np.float32), np.zeros((N, count), bool)
        for n in range(len(points)):  # the segment's points strided to icp.points, as ``refine`` reads them
            real = np.flatnonzero(mask[n])
            real = real[(np.arange(count) * len(real)) // count] if len(real) > count else real
            strided_points[n, :len(real)], strided_mask[n, :len(real)] = points[n, real], True
        scores, config = probs[:, self.model_class], self.config
        keep = self.episode.refine_config.models_per_class
        if self.same_models and keep is not None:
            top = np.array([points[n][mask[n], 2].max() if mask[n].any() else 0.0 for n in range(N)])
            gap = np.abs(self.height[None, :] - (top - self.spec.table_height)[:, None])  # [N, L]
            chosen = np.zeros_like(gap, bool)
            for c in np.unique(self.model_class):
                of_c = np.flatnonzero(self.model_class == c)
                best = of_c[np.argsort(gap[:, of_c], axis=1)[:, :keep]]
                np.put_along_axis(chosen, best, True, axis=1)
            scores = np.where(chosen, scores, -1.0)
            config = dataclasses.replace(config, top_k=self.episode.refine_config.top_k * keep)
        model, poses = open3d_refine(strided_points, strided_mask, scores, None, self.targets, config,
                                     self.spec.table_height, poses=HostPose)
        return self.model_class[model], poses

    def plan(self, corners: np.ndarray, poses: np.ndarray, views: np.ndarray, visited: np.ndarray,
             index: np.ndarray) -> int:
        """Eq. 5-8 over the candidate viewpoints ``index``: the paper's count (NumPy), history weight, argmax."""
        seen = numpy_paper(corners, poses, views[index], self.small).sum(axis=1)  # O_i
        position = views[:, :3, 3].astype(np.float64)
        d = np.linalg.norm(position[index][:, None] - position[None], axis=-1)
        sigma = self.episode.nbv_config.radius / 2
        weight = np.min(np.where(visited[None], 1.0 - np.exp(-(d**2) / (2 * sigma**2)), 1.0), axis=1)  # W_i
        utility = weight * seen / seen.max() if seen.max() > 0 else weight
        return int(index[np.argmax(utility)])

    def move(self, depth: np.ndarray, T_wc: np.ndarray, after: active.EpisodeState) -> tuple[dict[str, float], dict]:
        """One move on the frame (this episode's volume so far); NBV with ``after``'s (our move's) belief.
        Returns (ms per module, what it found)."""
        clock, times = time.perf_counter, {}
        t0 = clock()
        points, normals, mask = self.reconstruct(depth, T_wc)
        t1 = clock()
        segments = jax.block_until_ready(segment.segment(self.spec, points, normals, mask))
        t2 = clock()
        probs = np.asarray(pointnet.classify(self.spec.classifier, segments.points, segments.mask))
        t3 = clock()
        self.refine(np.asarray(segments.points), np.asarray(segments.mask), probs)
        t4 = clock()
        times.update(reconstruction=t1 - t0, segmentation=t2 - t1, classification=t3 - t2, refinement=t4 - t3)
        # The planner's inputs, taken from our state (not timed): candidates and aligned cuboids.
        index, ok = (np.asarray(a) for a in nbv.candidates(after.views, self.episode.nbv_config))
        belief = active.belief(self.episode, after)
        live = np.asarray(belief.live)
        corners, poses = np.asarray(belief.corners)[live], np.asarray(belief.poses)[live]
        views, visited = np.asarray(after.views.T_wc), np.asarray(after.views.visited)
        t5 = clock()
        next_view = self.plan(corners, poses, views, visited, index[ok]) if ok.any() else int(index[0])
        times["planning"] = clock() - t5
        found = {"surface": int(mask.sum()), "segments": int(np.asarray(segments.mask).any(axis=1).sum()),
                 "candidates": int(ok.sum()), "next_view": next_view}
        return {k: 1e3 * v for k, v in times.items()}, found


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=3, help="builtin scenes (seeds 0..n-1), one episode each")
    parser.add_argument("--moves", type=int, default=5, help="moves per episode (all but the first are timed)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds (each times every move of every scene)")
    parser.add_argument("--allocator", choices=("retain", "default"), default="retain",
                        help="retain: freed memory kept for reuse (jaxcls.allocator, as jaxcls's commands run); "
                             "default: glibc's own thresholds")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    if args.moves < 2:
        parser.error("--moves must be at least 2 (the first move is not timed)")
    import open3d as o3d

    retained = args.allocator == "retain" and allocator.retain_freed_memory()
    classifier = pointnet.load_classifier()
    start = time.perf_counter()
    scenes = [_scene(seed, args.moves, classifier) for seed in range(args.scenes)]
    warm_episode = time.perf_counter() - start
    print(f"warm-up episodes (rendering, compiling): {warm_episode:.1f} s", file=sys.stderr)
    episode = scenes[0].episode
    models = refine.library_models(scenes[0].object_set, episode.refine_config.library)
    assert tuple(m.name for m in models) == episode.library.names, "the peer's models are the episode's library"
    peer = Peer(episode, models)
    peer_same = Peer(episode, models, same_models=True)
    start = time.perf_counter()
    jax.block_until_ready(active.step_jit(episode, scenes[0].states[1], *scenes[0].frames[1]))
    compile_fused = time.perf_counter() - start

    def run_ours(scene: Scene, t: int) -> tuple[float, dict[str, float]]:
        start = time.perf_counter()
        state, times = active.timed_step(scene.episode, scene.states[t], *scene.frames[t])
        total = time.perf_counter() - start
        if int(state.next_view) != int(scene.states[t + 1].next_view):
            raise RuntimeError(f"move {t + 1}: timed_step is not deterministic (next view {int(state.next_view)} "
                               f"!= {int(scene.states[t + 1].next_view)})")
        return 1e3 * total, times

    def run_fused(scene: Scene, t: int) -> tuple[float, dict[str, float]]:
        start = time.perf_counter()
        jax.block_until_ready(active.step_jit(scene.episode, scene.states[t], *scene.frames[t]))
        return 1e3 * (time.perf_counter() - start), {}

    agree = {"next view": [0, 0]}
    found_log: list[dict] = []

    def run_peer(scene: Scene, t: int, peer: Peer = peer) -> tuple[float, dict[str, float]]:
        start = time.perf_counter()
        times, found = peer.move(*scene.frames[t], scene.states[t + 1])
        total = time.perf_counter() - start
        if not peer.same_models:
            found_log.append(found)
            agree["next view"][0] += found["next_view"] == int(scene.states[t + 1].next_view)
            agree["next view"][1] += 1
        return 1e3 * total, times

    def run_peer_same(scene: Scene, t: int) -> tuple[float, dict[str, float]]:
        return run_peer(scene, t, peer_same)

    names = {"ours": "jaxcls `active.timed_step` (stage by stage, each module jitted)",
             "fused": "jaxcls `active.step_jit` (the move in one jit)",
             "peer": "peer: Open3D ICP tracking + TSDF + scikit-learn segmentation + PointNet + Open3D ICP (every "
                     "model of the top-3 classes) + NumPy NBV",
             "peer_same": "peer, registering only the models ours registers (of each class the nearest in height)"}
    contenders = {"ours": run_ours, "fused": run_fused, "peer": run_peer, "peer_same": run_peer_same}
    for scene in scenes:  # warm-up of the peer's path (and of pointnet.classify's jit)
        for p in (peer, peer_same):
            p.reset(scene.episode)
            p.reconstruct(*scene.frames[0])
        for t in range(1, args.moves):
            run_peer(scene, t)
            run_peer_same(scene, t)
    agree["next view"], found_log[:] = [0, 0], []
    peer.tracking_ms.clear()
    totals = {k: [[] for _ in range(args.rounds)] for k in contenders}
    modules = {k: {m: [] for m in active.MODULES} for k in contenders}
    for r in range(args.rounds):
        for s, scene in enumerate(scenes):
            for p in (peer, peer_same):
                p.reset(scene.episode)
                p.reconstruct(*scene.frames[0])  # move 1, not timed (no surface yet: the reported pose)
            for t in range(1, args.moves):
                order = list(contenders) if (r + s + t) % 2 == 0 else list(reversed(contenders))
                for key in order:
                    total, times = contenders[key](scene, t)
                    totals[key][r].append(total)
                    for m, v in times.items():
                        modules[key][m].append(v)
        print(f"round {r + 1}: " + ", ".join(f"{k} {statistics.median(v[r]):.0f} ms" for k, v in totals.items()),
              file=sys.stderr)

    median = {k: statistics.median([x for r in v for x in r]) for k, v in totals.items()}
    cpu = report.cpu_name()
    rows = []
    for key in contenders:
        per_round = [statistics.median(r) for r in totals[key]]
        cells = [f"{statistics.median(modules[key][m]):.1f}" if modules[key][m] else "-" for m in active.MODULES]
        rows.append((names[key], cpu, *cells, f"{median[key]:.0f}", f"{min(per_round):.0f}-{max(per_round):.0f}",
                     f"{median['peer'] / median[key]:.1f}x", f"{median['peer_same'] / median[key]:.1f}x"))
    paper = [f"{1e3 * PAPER[m]:.0f}" if m in PAPER else "not given" for m in active.MODULES]
    rows.append(("the paper (Sec. 5: averaged time between consecutive moves)", "Alienware Aurora desktop, i7",
                 *paper, f"{1e3 * sum(PAPER.values()):.0f} (sum)", "-", "-", "-"))
    timed = args.scenes * (args.moves - 1)
    segments = [f["segments"] for f in found_log]
    notes = [
        f"Warm-up (rendering every frame, compiling `timed_step`'s stages): {warm_episode:.0f} s for {args.scenes} "
        f"episode{'s' * (args.scenes != 1)}; `step_jit`'s first call (compile): {compile_fused:.0f} s.",
        f"The peer's surface: median {statistics.median(f['surface'] for f in found_log):.0f} points above the "
        f"table; {statistics.median(segments):.0f} non-empty segments per move, each registered "
        f"{peer.config.top_k} models x {peer.config.hypotheses} yaws (Open3D, {o3d.__version__}).",
        "Reconstruction includes the camera tracking in both: ours registers the frame to the fused model "
        "(`tracking.register`, `TrackingConfig()` of the episode's perception) before fusing it; the peer's "
        "Open3D point-to-plane registration to its surface took a median "
        f"{statistics.median(peer.tracking_ms):.1f} ms of its reconstruction (`benchmarks/tracking.py` times both "
        "alone).",
        f"The peer's NBV scores the candidates within the radius (median "
        f"{statistics.median(f['candidates'] for f in found_log):.0f} per move; ours scores all "
        f"{episode.nbv_config.max_candidates}, masked); with our cuboids it picks our next view in "
        f"{agree['next view'][0]}/{agree['next view'][1]} moves.",
        f"Ours: GR of {episode.refine_config.hypotheses} learned yaws from the yaw head's estimate on "
        f"{episode.refine_config.models_per_class or 'every'} model(s) per candidate class, pruned per class "
        "(`setup.episode_refine()`), PointNet's yaw head in the same pass as the scores (`pointnet.predict`); the "
        f"peer: the same number of even yaws ({peer.config.hypotheses}), every (model, yaw) for 30 iterations; "
        "its model samples and initial poses are NumPy (`pose.initial_poses` called "
        "eagerly per segment and model would add ~0.4 s of JAX dispatch to its GR).",
    ]
    report.publish(report.section(
        f"One move of the active loop, ours against a peer composition, {datetime.date.today()}", argv,
        ("contender", "device", *(f"{COLUMNS[m]} ms" for m in active.MODULES), "median ms per move",
         "range over rounds", "speed-up (peer / this)", "speed-up (peer, same models / this)"), rows,
        intro=f"{args.scenes} builtin scene{'s' * (args.scenes != 1)} (640x480, mujoco), episodes of {args.moves} "
              f"moves from view {START}: {timed} timed moves (all but each episode's first) x {args.rounds} "
              "interleaved rounds; frames rendered beforehand. JAX and Open3D share the machine's cores"
              + (" and its allocator, set to keep freed memory (`jaxcls.allocator`). " if retained else
                 " and glibc's default allocator thresholds (`--allocator default`). ")
              + "Per-module columns: medians over the timed moves; the total is each move's wall clock.",
        notes=notes), args.out)


if __name__ == "__main__":
    main()
