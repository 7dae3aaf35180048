"""Geometric refinement of one move against Open3D: 5 segments x top-3 classes x 8 yaw hypotheses = 120
point-to-plane registrations of segments of up to 1024 points onto 2048 model samples.

    python benchmarks/refine.py [--rounds 7] [--scenes 3] [--out BENCHMARKS.md]

Segments: ``perception.observe`` on 3 views of held-out built-in scenes; candidates: the shipped
classifier's top 3; models: one per class (the scene's own instance for its classes, else the first
held-out instance), so a move is exactly 120 registrations. Ours: ``refine.refine_jit`` (one jitted,
vmapped call: every hypothesis for ``prune_after`` iterations, then the best rho per model for the rest),
in both DoF modes, with 512 points and more iterations, and a straightforward variant without pruning.
Open3D: ``registration_icp`` with ``TransformationEstimationPointToPlane``, the same 120 initial poses, 30
iterations each, one after another, then rho (Eq. 2) per registration from KD-trees, and Eq. 3-4. Each
round times every contender once, interleaved; the table gives medians and the spread over rounds, and
the final accuracy of each: the refined class right, the pose within 5 degrees (modulo symmetry) and 5 mm,
over the scenes' segments. The moves are ``jaxcls.experiments.moves``', the peer ``jaxcls.experiments.peers``'.
"""

from __future__ import annotations

import argparse
import datetime
import statistics
import time

import jax
import numpy as np

from jaxcls import metrics, report
from jaxcls.experiments.moves import observed_move
from jaxcls.experiments.peers import open3d_refine
from jaxcls.perception import icp, pointnet, refine


def _accuracy(refined, poses, world, truth, classes) -> tuple[int, int, int]:
    """(segments scored, class right, class right and pose within 5 degrees / 5 mm)."""
    scored = right = posed = 0
    for n in np.flatnonzero(truth.object >= 0):
        obj = truth.object[n]
        scored += 1
        if classes[int(refined[n])] == world.scene.objects[obj].class_name:
            right += 1
            angle, shift = metrics.pose_error(np.asarray(poses[n]), world.scene.object_poses()[obj],
                                              world.models[obj].yaw_symmetry)
            posed += angle <= 5.0 and shift <= 0.005
    return scored, right, posed


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7, help="timed rounds (each times every contender once)")
    parser.add_argument("--scenes", type=int, default=3, help="held-out scenes (one move each) per round")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    classifier = pointnet.load_classifier()
    moves = [observed_move(seed, classifier) for seed in range(args.scenes)]
    ours = {
        "jaxcls refine (default): yaw (4-DoF), 8 yaws x 3 + best x 9 iterations, 256 points": refine.RefineConfig(),
        "jaxcls refine, 6-DoF, otherwise the default": refine.RefineConfig(icp=icp.ICPConfig(
            dof="full", iterations=12, points=256)),
        "jaxcls refine, yaw, 512 points, 5 + 15 iterations": refine.RefineConfig(
            prune_after=5, icp=icp.ICPConfig(iterations=20, points=512)),
        "jaxcls refine, yaw, no pruning: 120 x 20 iterations, 512 points": refine.RefineConfig(
            prune_after=20, icp=icp.ICPConfig(iterations=20, points=512)),
    }
    contenders = {}
    for name, config in ours.items():
        libraries = [refine.ModelLibrary.build(models, classifier.classes, config.icp) for _, _, models, _ in moves]

        def run(config=config, libraries=libraries):
            outs = [refine.refine_jit(s.segments.points, s.segments.mask, s.probs, lib, config, w.table_height)
                    for (w, s, _, _), lib in zip(moves, libraries, strict=True)]
            return jax.block_until_ready(outs)

        contenders[name] = (run, lambda outs: [(np.asarray(o.refined), np.asarray(o.pose)) for o in outs])
    o3d_config = refine.RefineConfig()
    o3d_targets = [[icp.model_target(m, o3d_config.icp) for m in models] for _, _, models, _ in moves]

    def run_open3d():
        return [open3d_refine(np.asarray(s.segments.points), np.asarray(s.segments.mask), np.asarray(s.probs),
                              models, targets, o3d_config, w.table_height)
                for (w, s, models, _), targets in zip(moves, o3d_targets, strict=True)]

    contenders["Open3D registration_icp, 120 x 30 iterations, one after another (+ KD-tree rho)"] = (
        run_open3d, lambda outs: outs)
    first, results = {}, {}
    for name, (run, _) in contenders.items():
        start = time.perf_counter()
        results[name] = run()
        first[name] = time.perf_counter() - start
    times = {name: [] for name in contenders}
    for _ in range(args.rounds):
        for name, (run, _) in contenders.items():
            start = time.perf_counter()
            run()
            times[name].append((time.perf_counter() - start) / len(moves))
    reference = statistics.median(times[next(reversed(contenders))])
    rows = []
    for name, (_, unpack) in contenders.items():
        totals = np.zeros(3, int)
        for (world, _, _, truth), (refined, poses) in zip(moves, unpack(results[name]), strict=True):
            totals += _accuracy(refined, poses, world, truth, classifier.classes)
        median = statistics.median(times[name])
        rows.append((name, report.cpu_name(), f"{1000 * median:.1f}", f"{1000 * min(times[name]):.1f}-"
                     f"{1000 * max(times[name]):.1f}", f"{reference / median:.1f}x", f"{1000 * first[name]:.0f}",
                     f"{totals[1]}/{totals[0]}", f"{totals[2]}/{totals[0]}"))
    report.publish(report.section(
        f"Geometric refinement of one move against Open3D, {datetime.date.today()}", argv,
        ("registrations of one move (5 segments x 3 classes x 8 yaws)", "device", "median ms per move",
         "range over rounds", "speed-up over Open3D", "first call ms (all scenes)", "class right",
         "class right, pose within 5 deg / 5 mm"), rows,
        intro=f"{args.scenes} held-out scenes (one move of 3 fused views each), {args.rounds} interleaved rounds. "
              "Open3D runs on all cores (its ICP is multi-threaded); JAX's CPU backend likewise."), args.out)


if __name__ == "__main__":
    main()
