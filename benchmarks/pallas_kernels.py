"""The move's two Pallas kernels against the XLA programs they replace, each alone, batched as in Table 1's
program: the fusion (``perception.volume.kernel: pallas``: one kernel over blocks of voxels, in place) against the
vectorised fusion in slabs, and PointNet's pooled product (``perception.classification_pooling: pallas``: a
running max over the points, the product never written) against XLA's product then max.

    python benchmarks/pallas_kernels.py --batch 512 [--frames 4] [--repeats 5] [--out BENCHMARKS.md]
    python benchmarks/pallas_kernels.py --batch 512 --fusion-blocks 2048w4 8192w8 --pool-blocks 128x64w4 128x32w4a

The fusion: B compact 128^3 volumes (the scale configs' storage), each of its own, fusing ``--frames`` synthetic
640x480 frames in turn (a tilted plane of depths seen from a camera 0.8-1.2 m away) under ``lax.scan``, vmapped, as
an episode carries its volume, by each of ``--fusion-blocks`` (``tsdf.FusionBlocks``; default the move's
``FUSION_BLOCKS``); the pooling: B segments of 256 points x 128 channels into 1,024 (the pooled MLPs' widest),
bfloat16, by each of ``--pool-blocks`` (``pointnet.PoolBlocks``; default the networks' ``POOL_BLOCKS``). Each
program jitted apart, called in turns (``--repeats``), median milliseconds a call after a compiling call; the
outputs compared (fusion: the weights' share equal, the values' share differing and largest difference; pooling: the
largest difference, bfloat16). Off a GPU the kernels are interpreted (slow: use a small ``--batch``).
"""

from __future__ import annotations

import argparse
import functools
import re
import statistics
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import report
from jaxcls.geometry import Intrinsics, look_at
from jaxcls.perception import pointnet, tsdf


def fusion_inputs(batch: int, frames: int, seed: int = 0) -> tuple[tsdf.TSDFVolume, jax.Array, jax.Array]:
    """(B compact 128^3 volumes [B, ...], [B, F, 480, 640] depths, [B, F, 4, 4] poses): a tilted plane through the
    volumes' centre seen from cameras 0.8-1.2 m away around it (the volume fills the view, as in a move)."""
    rng = np.random.default_rng(seed)
    intr = Intrinsics.kinect_v1()
    volume = tsdf.create_volume(np.zeros(3))
    storage = tsdf.VolumeStorage.compact
    volume = volume.replace(tsdf=storage.encode(volume.tsdf), weight=volume.weight.astype(jnp.uint8))
    angles, distances = rng.uniform(0, 2 * np.pi, (batch, frames)), rng.uniform(0.8, 1.2, (batch, frames))
    eyes = np.stack([distances * np.cos(angles), distances * np.sin(angles), 0.6 * distances], axis=-1)
    poses = look_at(eyes.reshape(-1, 3), np.zeros(3)).reshape(batch, frames, 4, 4).astype(np.float32)
    v, u = np.mgrid[0:intr.height, 0:intr.width]
    plane = (0.1 * (u - intr.cx) / intr.fx + 0.05 * (v - intr.cy) / intr.fy).astype(np.float32)
    depths = jnp.asarray(distances, jnp.float32)[..., None, None] + jnp.asarray(plane)
    return jax.tree.map(lambda a: jnp.broadcast_to(a, (batch, *a.shape)) + 0, volume), depths, jnp.asarray(poses)


def agreement(stage: str, a, b) -> str:
    """How a kernel's output ``b`` agrees with the XLA program's ``a``."""
    if stage == "fusion":
        same = float(np.mean(np.asarray(a.weight) == np.asarray(b.weight)))
        gap = np.abs(np.asarray(a.values) - np.asarray(b.values))
        return (f"weights equal {same:.6f}; values: {np.mean(gap > 1e-4):.2e} of voxels differ by > 1e-4 "
                f"(a voxel projected to a neighbouring pixel), at most {gap.max():.2g}")
    real = np.isfinite(np.asarray(a, np.float32))
    return f"within {float(np.max(np.abs(np.asarray(a, np.float32) - np.asarray(b, np.float32))[real])):.2g}"


def parse_blocks(text: str) -> pointnet.PoolBlocks:
    """``CxPwW[gS][a]`` (e.g. ``128x64w4``, ``256x32w8g4a``): channels, points, warps, segments a program (1 unless
    given), ``a`` = accumulate."""
    match = re.fullmatch(r"(\d+)x(\d+)w(\d+)(?:g(\d+))?(a?)", text)
    if not match:
        raise argparse.ArgumentTypeError(f"--pool-blocks: {text!r} is not CxPwW[gS][a] (e.g. 128x64w4, 256x32w8g4a)")
    return pointnet.PoolBlocks(int(match[1]), int(match[2]), int(match[3]), bool(match[5]), int(match[4] or 1))


def parse_fusion_blocks(text: str) -> tsdf.FusionBlocks:
    """``VwW[sS]`` (e.g. ``2048w4``, ``8192w8s4``): voxels a program, warps, steps (1 unless given)."""
    match = re.fullmatch(r"(\d+)w(\d+)(?:s(\d+))?", text)
    if not match:
        raise argparse.ArgumentTypeError(f"--fusion-blocks: {text!r} is not VwW[sS] (e.g. 2048w4, 8192w8s4)")
    return tsdf.FusionBlocks(int(match[1]), int(match[2]), int(match[3] or 1))


def block_name(blocks: pointnet.PoolBlocks) -> str:
    group = f"g{blocks.segments}" if blocks.segments > 1 else ""
    return f"{blocks.channels}x{blocks.points}w{blocks.warps}{group}{'a' if blocks.accumulate else ''}"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=512, help="volumes (fusion) and segments (pooling) a call")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--frames", type=int, default=4, help="frames each volume fuses a call (the fusion)")
    parser.add_argument("--fusion-blocks", nargs="+", type=parse_fusion_blocks, default=[tsdf.FUSION_BLOCKS],
                        help="the fusion kernel's blocks to compare (tsdf.FusionBlocks as VwW[sS]: voxels a "
                             "program, warps, steps a program)")
    parser.add_argument("--pool-blocks", nargs="+", type=parse_blocks, default=[pointnet.POOL_BLOCKS],
                        help="the pooling kernel's blocks to compare (pointnet.PoolBlocks as CxPwW[gS][a]: channels a "
                             "program, points a step, warps, S segments a program, a = the max over the points at the "
                             "end)")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    intr = Intrinsics.kinect_v1()
    volumes, depths, poses = fusion_inputs(args.batch, args.frames)

    def fuse(kernel: tsdf.FusionKernel, slabs: int,
             blocks: tsdf.FusionBlocks = tsdf.FUSION_BLOCKS) -> Callable[..., tsdf.TSDFVolume]:
        def episode(volume: tsdf.TSDFVolume, depth: jax.Array, T_wc: jax.Array) -> tsdf.TSDFVolume:
            def frame(v: tsdf.TSDFVolume, f: tuple[jax.Array, jax.Array]) -> tuple[tsdf.TSDFVolume, None]:
                return tsdf.integrate(v, f[0], intr, f[1], slabs=slabs, kernel=kernel, blocks=blocks), None

            return jax.lax.scan(frame, volume, (depth, T_wc))[0]

        return jax.jit(jax.vmap(episode))

    rng = np.random.default_rng(1)
    x = jnp.asarray(rng.normal(size=(args.batch, 256, 128)), jnp.bfloat16)
    mask = jnp.asarray(rng.random((args.batch, 256)) < 0.8)
    w = jnp.asarray(rng.normal(size=(128, 1024)) * 0.1, jnp.float32)

    def product_then_max(x: jax.Array, mask: jax.Array, w: jax.Array) -> jax.Array:
        return pointnet._max_product(x, mask, w.astype(x.dtype))

    on_gpu = jax.default_backend() == "gpu"  # (elsewhere the kernels' `pallas` would be the XLA programs)
    fusion = tsdf.FusionKernel.pallas if on_gpu else tsdf.FusionKernel.interpreted
    kernel_name = "pallas" if on_gpu else "interpreted"

    def pooling(blocks: pointnet.PoolBlocks) -> Callable[..., jax.Array]:
        return jax.jit(functools.partial(pointnet._max_product_in_kernel, interpreted=not on_gpu, blocks=blocks))

    stages = {  # stage: (the XLA program, the kernels, inputs)
        "fusion": (("vectorised, 8 slabs (xla)", fuse(tsdf.FusionKernel.xla, 8)),
                   [(f"one kernel in place ({kernel_name}, {b.voxels}w{b.warps}{f's{b.steps}' * (b.steps > 1)})",
                     fuse(fusion, 1, b))
                    for b in args.fusion_blocks], (volumes, depths, poses)),
        "PointNet's pooled product": (("product then max (xla)", jax.jit(product_then_max)),
                                      [(f"running max ({kernel_name}, {block_name(b)})", pooling(b))
                                       for b in args.pool_blocks], (x, mask, w)),
    }
    rows = []
    for stage, (reference, ours, inputs) in stages.items():
        programs = dict([reference, *ours])
        for f in programs.values():  # (compiled first)
            jax.block_until_ready(f(*inputs))
        seconds, outputs = report.interleaved(
            {name: lambda f=f, inputs=inputs: f(*inputs) for name, f in programs.items()}, args.repeats)
        times = {name: [1e3 * s for s in t] for name, t in seconds.items()}
        base = statistics.median(times[reference[0]])
        for name in programs:
            ms = statistics.median(times[name])
            rows.append((stage, name, report.device_name(), args.batch, f"{ms:.2f}",
                         f"{min(times[name]):.2f}-{max(times[name]):.2f}", f"{base / ms:.2f}x",
                         "-" if name == reference[0] else agreement(stage, outputs[reference[0]], outputs[name])))
    report.publish(report.section(
        "The move's Pallas kernels against XLA's", argv,
        ("stage", "program", "device", "batch", "median ms a call", "range", "speed-up", "agreement"), rows,
        intro=f"{args.repeats} calls of each, in turns (``report.interleaved``), after a compiling call."), args.out)


if __name__ == "__main__":
    main()
