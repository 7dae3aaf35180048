"""Frame-to-model tracking of one depth frame on the CPU: ``tracking.register`` (+ ``accept``) against Open3D's
point-to-plane ``registration_icp`` onto the same fused model, on the same frames from the same initial poses,
interleaved in one process.

    python benchmarks/tracking.py [--scenes 3] [--frames 6] [--fused 5] [--rounds 3] [--variant levels=1 ...]
        [--out BENCHMARKS.md]

Scenes: the world of the shipped ``real_like`` dataset config (Kinect v1 noise at 640x480, a hand-eye error
shared by a scene's frames), ``mujoco`` backend, seeds 0..n-1. Per scene one ``World.measure`` of ``--fused``
evenly spread viewpoints and ``--frames`` others (drawn with the scene's seed): the fused views are integrated
at their TRUE poses (``observation.fuse``: foreground, then the TSDF) and the model's surface extracted
(``tsdf.extract_surface``, 16384 points), so the model sits in the true world; each further frame is then
registered to it from its REPORTED pose (the hand-eye error, ~8 mm at the objects):

- ours: ``tracking.register`` + ``tracking.accept`` in one module-level ``jax.jit`` with ``TrackingConfig()``
  (its pyramid levels and Gauss-Newton steps, projective association, the table term; the row says which); and, to
  attribute the cost, the same without the table term (``table=False``); and one row per ``--variant``
  (``TrackingConfig`` settings, e.g. ``levels=1,iterations=3``: what a cheaper registration loses);
- Open3D: ``registration_icp`` with ``TransformationEstimationPointToPlane`` (plain, and with a Huber kernel
  of ours' width), max correspondence 0.02 m, at most 20 iterations (relative fitness and RMSE 1e-6); source:
  the frame's foreground points in the camera frame, every 2nd pixel in both directions (ours' finest level),
  with depth within ``foreground.max_depth`` and above the table at the initial pose (the filter fusion
  applies); target: the model's surface points with their normals. Both clouds are built per frame inside the
  timed call (the build alone is also reported); Open3D builds the target's KD-tree inside every call.

Each round times every frame of every scene, the contenders in turn (the order flips from frame to frame);
"median ms per frame" is over all rounds' frames, "range over rounds" spans the rounds' medians. Accuracy, so
that speed is compared at known accuracy: with D = T_est @ inv(T_true), how far D moves the scene-centre point
(0, 0, table + 0.05) in mm and D's rotation angle in deg, medians and largest over the frames (deterministic:
taken from the warm-up call).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import functools
import os
import statistics
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import report
from jaxcls.config import load_config
from jaxcls.experiments.peers import ITERATIONS, MAX_CORRESPONDENCE, Open3DTracker
from jaxcls.geometry import Intrinsics
from jaxcls.perception import observation, tracking, tsdf
from jaxcls.perception.settings import PerceptionConfig, Spec
from jaxcls.world import make_world
from jaxcls.world.dataset import DatasetConfig

CENTRE_HEIGHT = 0.05  # m above the table: the point whose displacement is the translation error
SURFACE_POINTS = 16384  # the model's surface samples (``ShapeConfig.surface_points``' default)


@functools.partial(jax.jit, static_argnames=("intrinsics", "config"))
def _ours(depth: jax.Array, T_init: jax.Array, points: jax.Array, normals: jax.Array, mask: jax.Array,
          table_height: jax.Array, intrinsics: Intrinsics, config: tracking.TrackingConfig
          ) -> tuple[tracking.Fit, jax.Array]:
    """One frame registered to the model and checked: (``Fit``, [] bool accepted)."""
    fit = tracking.register(depth, intrinsics, T_init, points, normals, mask, table_height, config)
    return fit, tracking.accept(fit, T_init, config, jnp.zeros((), bool))


# --------------------------------------------------------------------------- scenes


@dataclasses.dataclass
class Scene:
    """One scene's model and the frames registered to it. surface: the model's points, normals [P, 3], mask
    [P] (device); host_points, host_normals: its real rows (NumPy); depth [K, H, W]; reported, true: [K, 4, 4]."""

    seed: int
    table_height: float
    surface: tsdf.Surface
    host_points: np.ndarray
    host_normals: np.ndarray
    depth: np.ndarray
    reported: np.ndarray
    true: np.ndarray
    fused_views: list[int]
    views: list[int]


def _scene(seed: int, fused: int, frames: int, world_config, object_set) -> tuple[Scene, Spec, Intrinsics]:
    world = make_world(world_config, seed=seed, object_set=object_set)
    V = len(world.viewpoints)
    fused_views = [int(v) for v in np.linspace(0, V, fused, endpoint=False)]
    rest = np.setdiff1d(np.arange(V), fused_views)
    views = [int(v) for v in np.sort(np.random.default_rng(seed).choice(rest, frames, replace=False))]
    depth, reported, _, true = world.measure(jax.random.PRNGKey(seed), fused_views + views)
    spec = Spec.create(PerceptionConfig(), world.intrinsics, world.table_height)
    volume = observation.empty_volume(spec)
    for k in range(fused):
        volume = observation.fuse(spec, volume, depth[k], true[k])
    surface = jax.block_until_ready(tsdf.extract_surface(volume, SURFACE_POINTS))
    mask = np.asarray(surface.mask)
    scene = Scene(seed=seed, table_height=float(world.table_height), surface=surface,
                  host_points=np.asarray(surface.points)[mask], host_normals=np.asarray(surface.normals)[mask],
                  depth=depth[fused:], reported=np.asarray(reported[fused:], np.float64),
                  true=np.asarray(true[fused:], np.float64), fused_views=fused_views, views=views)
    return scene, spec, world.intrinsics


def pose_errors(T_est: np.ndarray, T_true: np.ndarray, table_height: float) -> tuple[float, float]:
    """(mm the scene-centre point moves under D = T_est @ inv(T_true), D's rotation in deg)."""
    D = np.asarray(T_est, np.float64) @ np.linalg.inv(np.asarray(T_true, np.float64))
    c = np.array([0.0, 0.0, table_height + CENTRE_HEIGHT])
    return float(np.linalg.norm(D[:3, :3] @ c + D[:3, 3] - c) * 1e3), tracking.pose_error(D)[1]


# --------------------------------------------------------------------------- the benchmark


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=3, help="real-like scenes (seeds 0..n-1)")
    parser.add_argument("--frames", type=int, default=6, help="frames registered per scene")
    parser.add_argument("--fused", type=int, default=5, help="views fused (at their true poses) into each model")
    parser.add_argument("--rounds", type=int, default=3, help="rounds (each times every frame of every scene)")
    parser.add_argument("--variant", action="append", default=[], metavar="KEY=VALUE[,KEY=VALUE]",
                        help="a further row of ours with these TrackingConfig settings (repeatable)")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    import open3d as o3d

    load = os.getloadavg()[0]
    dataset = load_config(DatasetConfig, "real_like")
    world_config = dataclasses.replace(dataset.world_config(), backend="mujoco")
    from jaxcls.world.objects import object_set_from_config

    object_set = object_set_from_config(world_config.objects)
    start = time.perf_counter()
    built = [_scene(seed, args.fused, args.frames, world_config, object_set) for seed in range(args.scenes)]
    scenes = [s for s, _, _ in built]
    spec, intrinsics = built[0][1], built[0][2]
    print(f"scenes (rendering, fusing): {time.perf_counter() - start:.1f} s", file=sys.stderr)
    if any(i != intrinsics for _, _, i in built):
        raise ValueError("tracking: every scene must share the camera")

    floor_eps, max_depth = spec.config.foreground.table_eps, spec.config.foreground.max_depth
    configs = {"ours": tracking.TrackingConfig(), "ours_no_table": tracking.TrackingConfig(table=False)}
    variants = {f"ours, {v}": load_config(tracking.TrackingConfig, None, v.split(",")) for v in args.variant}
    configs |= variants
    trackers: dict[float, dict[str, Open3DTracker]] = {}

    def peer_trackers(scene: Scene) -> dict[str, Open3DTracker]:
        h = scene.table_height
        if h not in trackers:
            floor = h + floor_eps
            trackers[h] = {"open3d": Open3DTracker(intrinsics, floor, max_depth),
                           "open3d_huber": Open3DTracker(intrinsics, floor, max_depth, huber=configs["ours"].huber)}
        return trackers[h]

    build_ms: list[float] = []
    icp_ms: dict[str, list[float]] = {"open3d": [], "open3d_huber": []}

    def run_ours(key: str) -> Callable[[Scene, int], tuple[float, np.ndarray, bool]]:
        config = configs[key]

        def run(scene: Scene, k: int) -> tuple[float, np.ndarray, bool]:
            s = scene.surface
            start = time.perf_counter()
            fit, ok = jax.block_until_ready(_ours(scene.depth[k], scene.reported[k].astype(np.float32), s.points,
                                                  s.normals, s.mask, np.float32(scene.table_height), intrinsics,
                                                  config))
            return 1e3 * (time.perf_counter() - start), np.asarray(fit.pose), bool(ok)
        return run

    def run_peer(key: str) -> Callable[[Scene, int], tuple[float, np.ndarray, bool]]:
        def run(scene: Scene, k: int) -> tuple[float, np.ndarray, bool]:
            peer = peer_trackers(scene)[key]
            start = time.perf_counter()
            source = peer.source(scene.depth[k], scene.reported[k])
            target = peer.target(scene.host_points, scene.host_normals)
            built = time.perf_counter()
            result = peer.icp(source, target, scene.reported[k])
            end = time.perf_counter()
            if key == "open3d":
                build_ms.append(1e3 * (built - start))
            icp_ms[key].append(1e3 * (end - built))
            return 1e3 * (end - start), np.asarray(result.transformation), True
        return run

    contenders = {"ours": run_ours("ours"), "ours_no_table": run_ours("ours_no_table"),
                  **{key: run_ours(key) for key in variants},
                  "open3d": run_peer("open3d"), "open3d_huber": run_peer("open3d_huber")}
    DEFAULT = tracking.TrackingConfig()
    names = {
        "ours": ("jaxcls `tracking.register` + `accept` (jit), `TrackingConfig()`: strides "
                 f"{'/'.join(map(str, DEFAULT.strides()))} x {DEFAULT.iterations} steps, table term"),
        "ours_no_table": "jaxcls, the same without the table term (`table=False`)",
        "open3d": f"Open3D `registration_icp` point-to-plane, {ITERATIONS} iterations, "
                  f"{MAX_CORRESPONDENCE * 1e3:.0f} mm gate (clouds built per frame)",
        "open3d_huber": f"Open3D, the same with `HuberLoss({configs['ours'].huber})` (ours' robust width)",
        **{key: f"jaxcls, `{key[len('ours, '):]}`: strides {'/'.join(map(str, c.strides()))} x {c.iterations} steps"
           for key, c in variants.items()},
    }
    # Warm-up: compiles ours, and keeps every contender's poses (all deterministic) for the accuracy columns.
    first: dict[str, float] = {}
    poses = {key: [] for key in contenders}
    accepted = {key: [] for key in contenders}
    for key, run in contenders.items():
        for scene in scenes:
            for k in range(len(scene.views)):
                ms, pose, ok = run(scene, k)
                first.setdefault(key, ms)
                poses[key].append(pose)
                accepted[key].append(ok)
    build_ms.clear()
    for v in icp_ms.values():
        v.clear()

    totals = {key: [[] for _ in range(args.rounds)] for key in contenders}
    for r in range(args.rounds):
        for s, scene in enumerate(scenes):
            for k in range(len(scene.views)):
                order = list(contenders) if (r + s + k) % 2 == 0 else list(reversed(contenders))
                for key in order:
                    totals[key][r].append(contenders[key](scene, k)[0])
        print(f"round {r + 1}: " + ", ".join(f"{key} {statistics.median(v[r]):.1f} ms" for key, v in totals.items()),
              file=sys.stderr)

    truth = [(scene.true[k], scene.table_height) for scene in scenes for k in range(len(scene.views))]
    reported = [scene.reported[k] for scene in scenes for k in range(len(scene.views))]

    def errors(estimates: list[np.ndarray]) -> tuple[str, str]:
        e = np.array([pose_errors(T, T_true, h) for T, (T_true, h) in zip(estimates, truth, strict=True)])
        return (f"{np.median(e[:, 0]):.2f} ({e[:, 0].max():.2f})", f"{np.median(e[:, 1]):.3f} ({e[:, 1].max():.3f})")

    frames = len(truth)
    median = {key: statistics.median([x for r in v for x in r]) for key, v in totals.items()}
    cpu = report.cpu_name()
    rows = [("the reported pose (no registration)", "-", "-", "-", "-", "-", *errors(reported), "-")]
    for key in contenders:
        per_round = [statistics.median(r) for r in totals[key]]
        of_which = f"{statistics.median(icp_ms[key]):.1f}" if key in icp_ms else "-"
        ok = f"{sum(accepted[key])}/{frames}" if key.startswith("ours") else "no check"
        rows.append((names[key], cpu, f"{median[key]:.1f}", f"{min(per_round):.1f}-{max(per_round):.1f}", of_which,
                     f"{median['open3d'] / median[key]:.2f}x", *errors(poses[key]), ok))
    as_fused = [T if ok else T_rep for T, ok, T_rep in zip(poses["ours"], accepted["ours"], reported, strict=True)]
    sizes = [len(peer_trackers(scene)["open3d"].source(scene.depth[k], scene.reported[k]).points)
             for scene in scenes for k in range(len(scene.views))]
    notes = [
        f"Load average at the start: {load:.2f} (the machine is shared: other jobs may have run alongside). JAX's "
        "CPU backend and Open3D's OpenMP threads share the cores.",
        f"Ours' first call (compile): {first['ours']:.0f} ms (`table=False`: {first['ours_no_table']:.0f} ms).",
        f"Open3D's source: median {statistics.median(sizes):.0f} points a frame "
        f"({min(sizes)}-{max(sizes)}); target: median "
        f"{statistics.median(len(s.host_points) for s in scenes):.0f} model points; building both clouds: median "
        f"{statistics.median(build_ms):.1f} ms of the total (Open3D {o3d.__version__}).",
        "Ours as it would be fused (a refused frame at the reported pose): translation, rotation "
        + " / ".join(errors(as_fused)) + ".",
        "Frames per scene (seed: fused views; registered views): "
        + "; ".join(f"{s.seed}: {s.fused_views}; {s.views}" for s in scenes) + ".",
    ]
    report.publish(report.section(
        f"Frame-to-model tracking of one frame, ours against Open3D, {datetime.date.today()}", argv,
        ("registration of one frame", "device", "median ms per frame", "range over rounds", "of which ICP ms",
         "speed-up (Open3D / this)", "translation error mm, median (max)", "rotation error deg, median (max)",
         "accepted"), rows,
        intro=f"{args.scenes} real-like scene{'s' * (args.scenes != 1)} (the `real_like` config's world: Kinect v1 "
              f"noise, a hand-eye error per scene; 640x480, mujoco), each a model of {args.fused} views fused at "
              f"their true poses; {args.frames} further frame{'s' * (args.frames != 1)} per scene registered "
              f"from the reported pose ({frames} in all) x {args.rounds} interleaved rounds. Errors against the "
              f"true pose: the scene-centre point's displacement (mm) and the rotation (deg) of "
              f"T_est @ inv(T_true), medians (largest) over the {frames} frames."
              , notes=notes), args.out)


if __name__ == "__main__":
    main()
