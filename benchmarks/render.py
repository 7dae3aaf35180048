"""Depth-rendering throughput of every backend on one tabletop scene, 640x480 unless told otherwise.

    python benchmarks/render.py                       # CPU rows; GPU rows too where a GPU is present
    python benchmarks/render.py --out BENCHMARKS.md   # also append the table as a section

Rows: ``mujoco`` (C ray casting) with 1 worker and with every core over the scene's 100 hemisphere views
(target: 100 views in <= 5 s on 2 cores); ``mjx`` on the CPU (a few frames: O(rays x triangles));
on a GPU ``warp`` (MJX's batch renderer) and ``mjx`` batched. Agreement is against ``mujoco`` on the
same views: the fraction of pixels within 1 mm where both hit, and of object ids equal there.
Scenes: ``--scene trimesh`` (stand-in meshes from ``jaxcls.world.render.testing``) or ``builtin`` (the
world of ``make_world``: a builtin-set scene and its hemisphere views).
"""

from __future__ import annotations

import argparse
import datetime
import platform
import sys
import time
from collections.abc import Callable

import jax
import numpy as np

from jaxcls import report
from jaxcls.geometry import CameraConfig, Intrinsics, ViewpointConfig, hemisphere_viewpoints
from jaxcls.world import WorldConfig, make_world
from jaxcls.world.render import DepthFrames, make_renderer
from jaxcls.world.render import testing as primitives
from jaxcls.world.render.native import available_cores
from jaxcls.world.render.warp import warp_unavailable_reason
from jaxcls.world.scenes import SceneConfig


def build_scene(kind: str, scale: float, num_objects: int, seed: int, count: int):
    """(model, intrinsics, views [count, 4, 4] ``T_wc`` on the hemisphere of radius 1 m) of a ``kind`` scene:
    ``trimesh`` (stand-in meshes, ``render.testing``) or ``builtin`` (``make_world``: the builtin object set)."""
    intrinsics = Intrinsics.kinect_v1(scale)
    if kind == "trimesh":
        model = primitives.mesh_scene(intrinsics, num_objects=num_objects, seed=seed)
        return model, intrinsics, hemisphere_viewpoints(np.array([0.0, 0.0, 0.05]), count, radius=1.0)
    camera = CameraConfig.from_intrinsics(intrinsics)
    world = make_world(WorldConfig(scene=SceneConfig(num_objects=num_objects), camera=camera,
                                   viewpoints=ViewpointConfig(count=count, radius=1.0), backend="mujoco"), seed)
    return world.model, world.intrinsics, world.viewpoints


def agreement(ref: DepthFrames, other: DepthFrames) -> str:
    """'within 1 mm: x, ids: y' over pixels where both hit; plus the fraction whose hit/miss agrees."""
    a_depth, a_id = np.asarray(ref.depth), np.asarray(ref.object_id)
    b_depth, b_id = np.asarray(other.depth), np.asarray(other.object_id)
    both = (a_depth > 0) & (b_depth > 0)
    close = np.mean(np.abs(a_depth[both] - b_depth[both]) < 1e-3)
    ids = np.mean(a_id[both] == b_id[both])
    hits = np.mean((a_depth > 0) == (b_depth > 0))
    return f"1 mm: {close:.4f}, ids: {ids:.4f}, hit mask: {hits:.4f}"


def timed(fn: Callable[[], DepthFrames], repeats: int = 1) -> tuple[float, DepthFrames]:
    """(seconds per call, last result), waiting for JAX's asynchronous results."""
    start = time.perf_counter()
    for _ in range(repeats):
        out = fn()
        jax.block_until_ready(out.depth)
    return (time.perf_counter() - start) / repeats, out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=["trimesh", "builtin"], default="trimesh")
    parser.add_argument("--objects", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scale", type=float, default=1.0, help="resolution scale of 640x480")
    parser.add_argument("--views", type=int, default=100)
    parser.add_argument("--mjx-cpu-frames", type=int, default=1, help="0 skips the (slow) mjx CPU row")
    parser.add_argument("--warp-batch", type=int, default=512)
    parser.add_argument("--mjx-gpu-batch", type=int, default=4)
    parser.add_argument("--mjx-gpu-chunk", type=int, default=8192, help="rays per vmapped chunk on a GPU")
    parser.add_argument("--agreement-views", type=int, default=16)
    parser.add_argument("--skip", nargs="*", default=[], choices=["mujoco", "mjx-cpu", "warp", "mjx-gpu"])
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)

    model, intr, views = build_scene(args.scene, args.scale, args.objects, args.seed, args.views)
    cpu = f"{platform.processor() or platform.machine()}, {available_cores()} cores"
    gpu_reason = warp_unavailable_reason()
    has_gpu = jax.default_backend() == "gpu"
    gpu = jax.devices()[0].device_kind if has_gpu else None
    rows: list[tuple[str, str, str, str, str]] = []
    notes: list[str] = []
    res = f"{intr.width}x{intr.height}"
    triangles = int(np.sum(model.mesh_facenum))
    print(f"scene {args.scene}: {model.ngeom} geoms, {triangles} triangles, {res}", file=sys.stderr)

    native = make_renderer(model, intr, "mujoco")
    ref = native.render(views[: args.agreement_views])
    if "mujoco" not in args.skip:
        for workers in sorted({1, available_cores()}):
            renderer = make_renderer(model, intr, "mujoco", workers=workers)
            seconds, _ = timed(lambda r=renderer: r.render(views))
            rows.append(("mujoco", f"CPU ({cpu}), {workers} worker{'s' * (workers > 1)}", str(len(views)),
                         f"{len(views) / seconds:.1f} ({seconds:.2f} s for {len(views)} views)", "reference"))
            print(rows[-1], file=sys.stderr)

    if "mjx-cpu" not in args.skip and args.mjx_cpu_frames > 0:
        # O(rays x triangles): minutes per 640x480 frame on a small CPU, so one call by default, compile
        # included; with --mjx-cpu-frames N > 1 a compile call first, then N timed frames.
        with jax.default_device(jax.devices("cpu")[0]):
            renderer = make_renderer(model, intr, "mjx")
            first_s, out = timed(lambda: renderer.render(views[:1]))
            speed = f"{1 / first_s:.4f} (one call, compile included: {first_s:.0f} s)"
            if args.mjx_cpu_frames > 1:
                seconds, out = timed(lambda: renderer.render(views[:1]), args.mjx_cpu_frames)
                speed = f"{1 / seconds:.4f} (first call {first_s:.0f} s)"
        rows.append(("mjx", f"CPU ({cpu})", "1", speed,
                     agreement(DepthFrames(ref.depth[:1], ref.object_id[:1]), out)))
        print(rows[-1], file=sys.stderr)

    tiled = np.resize(views, (max(args.warp_batch, args.mjx_gpu_batch), 4, 4))
    if "warp" not in args.skip:
        if gpu_reason is not None:
            notes.append(f"warp skipped: {gpu_reason}")
        else:
            batch = tiled[: args.warp_batch]
            for kinematics in ("forward", "static"):
                renderer = make_renderer(model, intr, "warp", kinematics=kinematics)
                compile_s, _ = timed(lambda r=renderer: r.render(batch))
                seconds, _ = timed(lambda r=renderer: r.render(batch), 5)
                check = renderer.render(views[: args.agreement_views])
                rows.append((f"warp ({kinematics})", f"GPU ({gpu})", str(len(batch)),
                             f"{len(batch) / seconds:.0f} (first call {compile_s:.1f} s)", agreement(ref, check)))
                print(rows[-1], file=sys.stderr)

    if "mjx-gpu" not in args.skip:
        if not has_gpu:
            notes.append("mjx on GPU skipped: JAX sees no GPU")
        else:
            renderer = make_renderer(model, intr, "mjx", chunk=args.mjx_gpu_chunk)
            batch = tiled[: args.mjx_gpu_batch]
            compile_s, _ = timed(lambda: renderer.render(batch))
            seconds, _ = timed(lambda: renderer.render(batch), 2)
            check = renderer.render(views[: args.agreement_views])
            rows.append(("mjx", f"GPU ({gpu})", str(len(batch)),
                         f"{len(batch) / seconds:.1f} (first call {compile_s:.1f} s)", agreement(ref, check)))
            print(rows[-1], file=sys.stderr)

    table = report.section(
        f"Depth rendering, {res}, {args.scene} scene ({args.objects} objects, {triangles} triangles), "
        f"{datetime.date.today()}", argv,
        ("backend", "device", "batch", "frames/s", "agreement with mujoco"), rows, notes=notes)
    report.publish(table, args.out)


if __name__ == "__main__":
    main()
