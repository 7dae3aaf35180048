"""Scoring a move's candidate views (paper Eq. 5): ~20 candidates x 5 aligned model cuboids, ours (hard
"paper", "exact", soft; one jitted call; and the volumetric information gain on a 128^3 TSDF) against a
NumPy version of the paper's count (project the 8 corners, fill the hull, paint near to far) in the same
run.

    python benchmarks/nbv.py [--rounds 20] [--scenes 5] [--batch 4096] [--out BENCHMARKS.md]

Scenes: 5 boxes upright within 0.25 m of the origin, random sizes and yaws; candidates: the 20 viewpoints
of the paper's 100-view hemisphere (r = 1 m) nearest a random one. Each round times every contender once on
every scene, interleaved; the table gives medians and the spread over rounds. ``--batch B`` also times B
candidate views in one call (the GPU figure: candidate views scored per second).
"""

from __future__ import annotations

import argparse
import datetime
import statistics
import time

import jax
import numpy as np
from scipy.spatial.transform import Rotation

from jaxcls import report
from jaxcls.experiments.peers import numpy_paper
from jaxcls.geometry import Intrinsics, hemisphere_viewpoints
from jaxcls.planning import visibility as vis

K = Intrinsics.kinect_v1(1.0)


def _scene(rng: np.random.Generator, views: np.ndarray, count: int = 20):
    half = rng.uniform([0.02, 0.02, 0.03], [0.06, 0.06, 0.10], (5, 3))
    corners = np.stack([np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (0, 2)]) * h
                        for h in half]).astype(np.float32)
    poses = np.tile(np.eye(4), (5, 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi, (5, 1))).as_matrix()
    poses[:, :2, 3] = rng.uniform(-0.2, 0.2, (5, 2))
    here = views[rng.integers(len(views)), :3, 3]
    near = np.argsort(np.linalg.norm(views[:, :3, 3] - here, axis=1))[1:count + 1]
    return corners, poses.astype(np.float32), views[near].astype(np.float32)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--scenes", type=int, default=5)
    parser.add_argument("--scale", type=float, default=0.25, help="of 640 x 480 (0.25: 160 x 120)")
    parser.add_argument("--batch", type=int, nargs="*", default=[], help="also time this many views per call")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    views = hemisphere_viewpoints(np.zeros(3), 100)
    scenes = [_scene(rng, views) for _ in range(args.scenes)]
    live = np.ones(5, bool)
    small = vis.scaled(K, args.scale)
    configs = {f"jaxcls {mode}": vis.VisibilityConfig(scale=args.scale, mode=mode) for mode in ("paper", "exact")}
    contenders = {name: (lambda c, p, T, config=config: vis.counts_jit(c, p, live, T, K, config))
                  for name, config in configs.items()}
    soft = vis.VisibilityConfig(scale=args.scale)
    contenders["jaxcls soft (differentiable)"] = lambda c, p, T: vis.soft_counts_jit(c, p, live, T, K, soft)
    from jaxcls.perception import tsdf
    from jaxcls.planning import information

    volume = tsdf.create_volume(np.array([0.0, 0.0, 0.3]), 0.6, 128)  # the loop's 128^3 cube, half observed
    half = np.asarray(volume.origin)[0] + np.arange(128) * volume.voxel_size < 0
    volume = volume.replace(weight=volume.weight.at[half].set(1.0))
    contenders["jaxcls info_gain (128^3 volume, 40x30 rays per view)"] = (
        lambda c, p, T: information.gain_jit(volume, T, K))
    contenders["NumPy/SciPy: hull of the projected corners, painted near to far"] = (
        lambda c, p, T: numpy_paper(c, p, T, small))
    for fn in contenders.values():  # compile
        jax.block_until_ready(fn(*scenes[0]))
    times = {name: [] for name in contenders}
    for _ in range(args.rounds):
        for name, fn in contenders.items():
            start = time.perf_counter()
            for scene in scenes:
                jax.block_until_ready(fn(*scene))
            times[name].append((time.perf_counter() - start) / len(scenes))
    reference = statistics.median(times[next(reversed(contenders))])
    rows = [(name, report.device_name(), len(scenes[0][2]), f"{small.width}x{small.height}",
             f"{1000 * statistics.median(t):.2f}", f"{1000 * min(t):.2f}-{1000 * max(t):.2f}",
             f"{reference / statistics.median(t):.1f}x") for name, t in times.items()]
    for B in args.batch:
        T = np.concatenate([scenes[0][2]] * (B // len(scenes[0][2]) + 1))[:B]
        fn = configs["jaxcls paper"]
        jax.block_until_ready(vis.counts_jit(scenes[0][0], scenes[0][1], live, T, K, fn))
        t = []
        for _ in range(5):
            start = time.perf_counter()
            jax.block_until_ready(vis.counts_jit(scenes[0][0], scenes[0][1], live, T, K, fn))
            t.append(time.perf_counter() - start)
        rows.append((f"jaxcls paper, {B} views in one call", report.device_name(), B, f"{small.width}x{small.height}",
                     f"{1000 * statistics.median(t):.2f}", f"{1000 * min(t):.2f}-{1000 * max(t):.2f}",
                     f"{B / statistics.median(t):,.0f} views/s"))
    report.publish(report.section(
        f"Scoring a move's candidate views (Eq. 5), {datetime.date.today()}", argv,
        ("contender", "device", "candidate views", "resolution", "median ms per move", "range over rounds",
         "speed-up over NumPy"), rows,
        intro=f"{args.scenes} scenes of 5 boxes, 20 candidates each, {args.rounds} interleaved rounds."), args.out)


if __name__ == "__main__":
    main()
