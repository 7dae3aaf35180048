"""TSDF fusion speed: one 640x480 integration into the default 128^3 volume, and one surface extraction.

    python benchmarks/tsdf.py                       # CPU rows (perception.tsdf jitted vs Open3D); GPU rows too
    python benchmarks/tsdf.py --out BENCHMARKS.md   # also append the table as a section

The frame is a builtin 5-object scene (``make_world``) rendered by the ``mujoco`` backend from one
hemisphere view; the volume is centred on the scene's centroid and fuses the raw frame (the stage alone,
not ``perception.observe``'s move). Times are medians over ``--repeats`` calls after a warm-up call
(compile included in "first call"), waiting for JAX's asynchronous results. Open3D's legacy
``UniformTSDFVolume`` runs on the same frame in the same process. "agreement" is the symmetric chamfer
distance between the two extracted surfaces, in voxels.
On a GPU: ``integrate`` vmapped over a batch of episodes' volumes, in integrations/s.
"""

from __future__ import annotations

import argparse
import datetime
import sys

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import report
from jaxcls.perception import tsdf
from jaxcls.world import WorldConfig, make_world


def chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Mean of the two directed mean nearest-neighbour distances between ``a: [N, 3]`` and ``b: [M, 3]``."""
    from scipy.spatial import cKDTree

    return 0.5 * (cKDTree(b).query(a)[0].mean() + cKDTree(a).query(b)[0].mean())


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--view", type=int, default=30, help="index of the hemisphere view (of 100)")
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--size", type=float, default=0.6)
    parser.add_argument("--max-points", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--gpu-batch", type=int, nargs="*", default=[16, 64])
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)

    world = make_world(WorldConfig(backend="mujoco"), args.seed)  # Kinect v1, 100 views at 1 m
    centre = world.centroid
    intr = world.intrinsics
    T_wc = world.poses([args.view])[0]
    depth = np.asarray(world.render([args.view]).depth[0])
    tsdf.check_frame(depth, intr, T_wc)
    volume = tsdf.create_volume(centre, size=args.size, resolution=args.resolution)
    res, grid = f"{intr.width}x{intr.height}", f"{args.resolution}^3"
    cpu_device = jax.devices("cpu")[0]
    cpu = report.cpu_name()
    rows: list[tuple[str, ...]] = []
    notes: list[str] = []
    extraction = f"jaxcls.perception.tsdf `extract_surface` (max_points={args.max_points})"

    with jax.default_device(cpu_device):
        d, T = jnp.asarray(depth), jnp.asarray(T_wc, jnp.float32)
        first, med, fused = report.timed(lambda: tsdf.integrate(volume, d, intr, T), args.repeats)
        rows.append(("jaxcls.perception.tsdf `integrate` (jit)", cpu, f"{med * 1e3:.1f}", f"{first * 1e3:.0f}", ""))
        print(rows[-1], file=sys.stderr)
        first, med, surface = report.timed(lambda: tsdf.extract_surface(fused, args.max_points), args.repeats)
        ours = np.asarray(surface.points)[np.asarray(surface.mask)]
        rows.append((extraction, cpu, f"{med * 1e3:.1f}", f"{first * 1e3:.0f}", f"{len(ours)} points"))
        print(rows[-1], file=sys.stderr)

    try:
        import open3d as o3d
    except ImportError:
        notes.append("Open3D rows skipped: open3d is not installed")
    else:
        integration = o3d.pipelines.integration
        # Open3D's origin is the cube's corner; its voxel centres are half a voxel inside it.
        peer = integration.UniformTSDFVolume(args.size, args.resolution, volume.truncation,
                                             integration.TSDFVolumeColorType.NoColor,
                                             np.asarray(centre, float) - args.size / 2)
        K = o3d.camera.PinholeCameraIntrinsic(intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy)
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.zeros((*depth.shape, 3), np.uint8)), o3d.geometry.Image(depth.astype(np.float32)),
            depth_scale=1.0, depth_trunc=100.0, convert_rgb_to_intensity=False)
        extrinsic = np.linalg.inv(T_wc)

        first, med, _ = report.timed(lambda: peer.integrate(rgbd, K, extrinsic), args.repeats)
        rows.append(("Open3D `UniformTSDFVolume.integrate`", cpu, f"{med * 1e3:.1f}", f"{first * 1e3:.0f}", ""))
        print(rows[-1], file=sys.stderr)
        peer.reset()
        peer.integrate(rgbd, K, extrinsic)  # the surface of one frame, as ours
        first, med, cloud = report.timed(peer.extract_point_cloud, args.repeats)
        theirs = np.asarray(cloud.points)
        rows.append(("Open3D `extract_point_cloud`", cpu, f"{med * 1e3:.1f}", f"{first * 1e3:.0f}",
                     f"{len(theirs)} points; chamfer to ours {chamfer(ours, theirs) / volume.voxel_size:.3f} voxels"))
        print(rows[-1], file=sys.stderr)

    if jax.default_backend() == "gpu":
        gpu = f"GPU ({jax.devices()[0].device_kind})"
        batched = jax.jit(jax.vmap(lambda v, d, T: tsdf.integrate(v, d, intr, T)))
        for batch in args.gpu_batch:
            vols = jax.tree.map(lambda x, b=batch: jnp.broadcast_to(x, (b, *x.shape)), volume)
            ds = jnp.broadcast_to(jnp.asarray(depth), (batch, *depth.shape))
            Ts = jnp.broadcast_to(jnp.asarray(T_wc, jnp.float32), (batch, 4, 4))
            first, med, _ = report.timed(lambda v=vols, d=ds, T=Ts: batched(v, d, T), args.repeats)
            rows.append((f"jaxcls.perception.tsdf `integrate`, vmap over {batch} volumes", gpu, f"{med * 1e3:.2f}",
                         f"{first * 1e3:.0f}", f"{batch / med:.0f} integrations/s"))
            print(rows[-1], file=sys.stderr)
        vol_gpu = jax.device_put(volume)
        first, med, fused = report.timed(lambda: tsdf.integrate(vol_gpu, jnp.asarray(depth), intr,
                                                                jnp.asarray(T_wc, jnp.float32)), args.repeats)
        rows.append(("jaxcls.perception.tsdf `integrate`", gpu, f"{med * 1e3:.2f}", f"{first * 1e3:.0f}", ""))
        first, med, _ = report.timed(lambda: tsdf.extract_surface(fused, args.max_points), args.repeats)
        rows.append((extraction, gpu, f"{med * 1e3:.2f}", f"{first * 1e3:.0f}", ""))
    else:
        notes.append("GPU rows skipped: JAX sees no GPU")

    table = report.section(
        f"TSDF fusion, {res} depth into {grid} voxels ({args.size} m cube, {volume.voxel_size * 1e3:.2f} mm "
        f"voxels), {datetime.date.today()}", argv,
        ("operation", "device", f"median ms ({args.repeats} calls)", "first call ms", "notes"), rows, notes=notes)
    report.publish(table, args.out)


if __name__ == "__main__":
    main()
