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
over the scenes' segments.
"""

from __future__ import annotations

import argparse
import datetime
import statistics
import time

import jax
import numpy as np
from scipy.spatial import cKDTree

from jaxcls import metrics, report
from jaxcls.geometry import CameraConfig
from jaxcls.perception import Spec, icp, init_state, observe, pointnet, pose, refine
from jaxcls.perception.settings import PerceptionConfig
from jaxcls.world import WorldConfig, make_world


def _move(seed: int, classifier: pointnet.Classifier):
    """One move's inputs of scene ``seed``: segments, scores, a library of one model per class, truth."""
    world = make_world(WorldConfig(camera=CameraConfig.kinect_v1(0.5), backend="mujoco"), seed=seed)
    spec = Spec.create(PerceptionConfig(), world.intrinsics, world.table_height, classifier)
    state = init_state(spec)
    for depth, T in zip(world.render([0, 10, 20]).depth, world.poses([0, 10, 20]), strict=True):
        state = observe(spec, state, depth, T)
    own = {m.class_name: m for m in world.models}
    models = [own.get(c) or next(m for m in world.object_set.test if m.class_name == c) for c in classifier.classes]
    owners = metrics.PointOwners(world.scene, world.models)
    points, mask = np.asarray(state.segments.points), np.asarray(state.segments.mask)
    truth = metrics.segment_truth(owners(points.reshape(-1, 3), mask.reshape(-1)).reshape(mask.shape), mask)
    return world, state, models, truth


def _open3d_move(points, mask, probs, models, targets, config: refine.RefineConfig, table_height: float):
    """Eq. 2-4 with Open3D's ICP, one registration after another: (refined class [N], pose [N, 4, 4])."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    clouds = []
    for t in targets:
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(t.samples()[0], np.float64)))
        cloud.normals = o3d.utility.Vector3dVector(np.asarray(t.samples()[1], np.float64))
        clouds.append((cloud, cKDTree(np.asarray(t.samples()[0], np.float64))))
    criteria = reg.ICPConvergenceCriteria(1e-6, 1e-6, 30)
    refined, poses = [], []
    for n in range(len(points)):
        seen = points[n][mask[n]].astype(np.float64)
        if len(seen) < 3:
            refined.append(int(np.argmax(probs[n])))
            poses.append(np.eye(4))
            continue
        source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(seen))
        best = (-1.0, 0, np.eye(4))
        for c in np.argsort(-probs[n])[: config.top_k]:
            cloud, tree = clouds[c]
            inits = np.asarray(pose.initial_poses(points[n], mask[n], np.asarray(targets[c].samples()[0]).mean(0),
                                                  table_height, pose.even_yaws(config.hypotheses)), np.float64)
            for T0 in inits:
                result = reg.registration_icp(source, cloud, config.icp.max_correspondence, np.linalg.inv(T0),
                                              reg.TransformationEstimationPointToPlane(), criteria)
                T = result.transformation
                moved = seen @ T[:3, :3].T + T[:3, 3]
                near = tree.query(moved)[0] <= config.icp.inlier_distance
                covered = cKDTree(moved).query(np.asarray(cloud.points))[0] <= config.icp.inlier_distance
                rho = near.mean() * covered.mean()
                if rho > best[0]:
                    best = (rho, int(c), np.linalg.inv(T))
        refined.append(best[1])
        poses.append(best[2])
    return np.asarray(refined), np.stack(poses)


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
    moves = [_move(seed, classifier) for seed in range(args.scenes)]
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
        return [_open3d_move(np.asarray(s.segments.points), np.asarray(s.segments.mask), np.asarray(s.probs),
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
