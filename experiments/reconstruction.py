"""How good is the fused reconstruction? Surface error of TSDF fusion against the true object meshes.

    python experiments/reconstruction.py --config configs/synthetic.yaml [key=value ...] [--out RESULTS.md]

For each scene of a dataset config (its world from ``make_world``): measure every viewpoint through the
config's sensor model (``world.measure``, as ``jaxcls dataset`` does, so the real-like config fuses noisy
depth from noisy poses), fuse ``--views`` of them spread over the hemisphere into a 0.6 m / 128^3 volume
centred on the scene, extract the surface, and measure the exact point-to-triangle distance of the
object points to the posed meshes (Open3D's raycasting scene, a test dependency). The whole frame is
fused, table included (the TSDF stage alone, not ``perception.observe``'s move): object points are those
closer to an object mesh than to the table plane, so that noisy table points are not counted as object
error. Reports the median and 90th percentile per scene and over all. ``--config`` takes a path or a
shipped config name (``synthetic``, ``real_like``).
"""

from __future__ import annotations

import argparse

import jax.numpy as jnp
import numpy as np
import open3d as o3d
from tqdm.auto import tqdm

from jaxcls import report
from jaxcls.config import load_config
from jaxcls.perception import tsdf
from jaxcls.world import make_world, scenes
from jaxcls.world.dataset import DatasetConfig, scene_key, scene_seeds
from jaxcls.world.objects import object_set_from_config


def distances_to_meshes(points: np.ndarray, scene: scenes.Scene, models) -> np.ndarray:
    """[P] exact distance (m) of ``points: [P, 3]`` to the union of the scene's posed object meshes."""
    raycast = o3d.t.geometry.RaycastingScene()
    for model, pose in zip(models, scene.object_poses(), strict=True):
        mesh = model.mesh.copy().apply_transform(pose)
        raycast.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                              o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    return raycast.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/synthetic.yaml")
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--out", help="append the table to this Markdown file")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_intermixed_args(argv)  # overrides may come before or after options
    cfg = load_config(DatasetConfig, args.config, args.overrides)
    object_set = object_set_from_config(cfg.objects)
    intrinsics = cfg.camera.intrinsics()
    chosen = np.linspace(0, cfg.viewpoints.count - 1, args.views).round().astype(int)
    rows, every = [], []
    for i, seed in enumerate(tqdm(scene_seeds(cfg.seed, cfg.num_scenes), desc="scenes")):
        world = make_world(cfg.world_config(), seed, object_set=object_set)
        scene, models = world.scene, world.models
        # Every view through the sensor model, as ``jaxcls dataset`` writes them (the same noise draw), then
        # the chosen ones: depth after the sensor model, the poses the pipeline is told.
        depth, T_wc, _, _ = world.measure(scene_key(cfg.seed, i), np.arange(len(world.viewpoints)), cfg.batch_size)
        volume = tsdf.create_volume(world.centroid)
        volume = tsdf.integrate_frames(volume, jnp.asarray(depth[chosen]), intrinsics,
                                       jnp.asarray(T_wc[chosen], jnp.float32))
        surface = tsdf.extract_surface(volume, max_points=200_000)
        points = np.asarray(surface.points)[np.asarray(surface.mask)]
        to_objects = distances_to_meshes(points, scene, models)
        closer = to_objects <= np.abs(points[:, 2] - scene.table_height)
        objects, d = points[closer], to_objects[closer] * 1000
        every.append(d)
        rows.append((i, len(objects), f"{np.median(d):.2f}", f"{np.percentile(d, 90):.2f}"))
    d = np.concatenate(every)
    rows.append(("all", len(d), f"{np.median(d):.2f}", f"{np.percentile(d, 90):.2f}"))
    table = report.section(
        f"TSDF surface error, `{args.config}` {' '.join(args.overrides)}".rstrip(), argv,
        ("scene", "object points", "median error (mm)", "90th percentile (mm)"), rows,
        intro=f"{args.views} views (indices {chosen.tolist()}) fused into 0.6 m / 128^3 "
              f"({volume.voxel_size * 1000:.2f} mm voxels), {intrinsics.width}x{intrinsics.height}.")
    report.publish(table, args.out)


if __name__ == "__main__":
    main()
