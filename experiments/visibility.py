"""What the cuboid approximation of Eq. 5 costs: visible pixels of each object counted from its aligned
bounding cuboid (``planning.visibility``, the paper's hull-and-z-buffer and the per-pixel z-buffer) against
the object's own mesh ray-cast by the project's renderer (MuJoCo), at every viewpoint of held-out scenes.

    python experiments/visibility.py [--scenes 10] [--scale 0.25] [--out RESULTS.md]

Poses are the ground truth (the cuboids of perfectly refined segments). Per scene and viewpoint the scores are
the per-object pixel counts and their sum O_i (Eq. 5); reported: the cuboids' excess over the mesh pixels,
how well O_i ranks the viewpoints (Spearman's rho over the 100 views, and the share of the best mesh view's
O reached by the best cuboid view), and how well each object's own count does (what the uncertainty-weighted
policy reads; the two cuboid modes differ only there: their totals are the same union of pixels).
"""

from __future__ import annotations

import argparse
import statistics

import numpy as np
from scipy.stats import spearmanr

from jaxcls import report
from jaxcls.geometry import CameraConfig
from jaxcls.planning import visibility as vis
from jaxcls.world import WorldConfig, make_world
from jaxcls.world.dataset import scene_seeds


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--scale", type=float, default=0.25, help="of 640 x 480: the renderer and the count")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    rows, stats = [], {m: {"excess": [], "spearman": [], "reached": [], "object": []} for m in ("paper", "exact")}
    for seed in scene_seeds(0, args.scenes):
        world = make_world(WorldConfig(camera=CameraConfig.kinect_v1(args.scale), backend="mujoco"), seed)
        views = np.arange(len(world.viewpoints))
        ids = np.asarray(world.render(views).object_id)  # [V, H, W]
        mesh = np.stack([(ids == j).sum(axis=(1, 2)) for j in range(len(world.models))], axis=1).astype(float)
        corners = np.stack([m.cuboid_corners for m in world.models]).astype(np.float32)
        poses = world.scene.object_poses().astype(np.float32)
        live = np.ones(len(corners), bool)
        for mode in ("paper", "exact"):
            cuboid = np.asarray(vis.counts_jit(corners, poses, live, world.poses(views).astype(np.float32),
                                               world.intrinsics, vis.VisibilityConfig(scale=1.0, mode=mode)))
            stats[mode]["excess"].append(cuboid.sum() / max(mesh.sum(), 1) - 1)
            O_cuboid, O_mesh = cuboid.sum(axis=1), mesh.sum(axis=1)
            stats[mode]["spearman"].append(spearmanr(O_cuboid, O_mesh).statistic)
            stats[mode]["reached"].append(O_mesh[np.argmax(O_cuboid)] / O_mesh.max())
            stats[mode]["object"] += [spearmanr(cuboid[:, j], mesh[:, j]).statistic for j in range(len(corners))
                                      if mesh[:, j].std() > 0]
    for mode, s in stats.items():
        rows.append((mode, args.scenes, f"{100 * statistics.median(s['excess']):+.0f}%",
                     f"{min(s['excess']) * 100:+.0f}% to {max(s['excess']) * 100:+.0f}%",
                     f"{statistics.median(s['spearman']):.3f}", f"{min(s['spearman']):.3f}",
                     f"{statistics.median(s['reached']):.3f}", f"{min(s['reached']):.3f}",
                     f"{statistics.median(s['object']):.3f}"))
    report.publish(report.section(
        "The cuboid approximation of Eq. 5 against the objects' meshes", argv,
        ("cuboid count", "scenes", "pixels, cuboids over meshes (median)", "range", "Spearman of O_i over the "
         "100 views (median)", "worst scene", "mesh O at the best cuboid view / best mesh O (median)", "worst",
         "per object: Spearman of its pixels over the views (median)"),
        rows, intro=f"Held-out synthetic scenes (5 objects, ground-truth poses), all 100 viewpoints, images at "
                    f"{args.scale} of 640 x 480; meshes ray-cast by MuJoCo (`world.render`)."), args.out)


if __name__ == "__main__":
    main()
