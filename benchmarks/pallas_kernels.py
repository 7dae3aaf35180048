"""The move's two Pallas kernels against the XLA programs they replace, each alone, batched as in Table 1's
program: the fusion (``perception.volume.kernel: pallas``: one kernel over blocks of 2,048 voxels, in place) against the
vectorised fusion in slabs, and PointNet's pooled product (``perception.classification_pooling: pallas``: a
running max over the points, the product never written) against XLA's product then max.

    python benchmarks/pallas_kernels.py --batch 512 [--frames 4] [--repeats 5] [--out BENCHMARKS.md]

The fusion: B compact 128^3 volumes (the scale configs' storage), each of its own, fusing ``--frames`` synthetic
640x480 frames in turn (a tilted plane of depths seen from a camera 0.8-1.2 m away) under ``lax.scan``, vmapped,
as an episode carries its volume; the pooling: B segments of
256 points x 128 channels into 1,024 (the pooled MLPs' widest), bfloat16. Each pair jitted apart, called in
turns (``--repeats``), median milliseconds a call after a compiling call; the outputs compared (fusion: the
weights' share equal, the values' share differing and largest difference; pooling: the largest difference,
bfloat16). Off a GPU the kernels are interpreted (slow: use a small ``--batch``).
"""

from __future__ import annotations

import argparse
import functools
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


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=512, help="volumes (fusion) and segments (pooling) a call")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--frames", type=int, default=4, help="frames each volume fuses a call (the fusion)")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    intr = Intrinsics.kinect_v1()
    volumes, depths, poses = fusion_inputs(args.batch, args.frames)

    def fuse(kernel: tsdf.FusionKernel, slabs: int) -> Callable[..., tsdf.TSDFVolume]:
        def episode(volume: tsdf.TSDFVolume, depth: jax.Array, T_wc: jax.Array) -> tsdf.TSDFVolume:
            def frame(v: tsdf.TSDFVolume, f: tuple[jax.Array, jax.Array]) -> tuple[tsdf.TSDFVolume, None]:
                return tsdf.integrate(v, f[0], intr, f[1], slabs=slabs, kernel=kernel), None

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
    pairs = {
        "fusion": (("vectorised, 8 slabs (xla)", fuse(tsdf.FusionKernel.xla, 8)),
                   (f"one kernel in place ({fusion})", fuse(fusion, 1)), (volumes, depths, poses)),
        "PointNet's pooled product": (("product then max (xla)", jax.jit(product_then_max)),
                                      (f"running max ({fusion})", jax.jit(functools.partial(
                                          pointnet._max_product_in_kernel, interpreted=not on_gpu))),
                                      (x, mask, w)),
    }
    rows = []
    for stage, (reference, ours, inputs) in pairs.items():
        for _, f in (reference, ours):  # (compiled first)
            jax.block_until_ready(f(*inputs))
        seconds, outputs = report.interleaved(
            {name: lambda f=f, inputs=inputs: f(*inputs) for name, f in (reference, ours)}, args.repeats)
        times = {name: [1e3 * s for s in t] for name, t in seconds.items()}
        a, b = outputs[reference[0]], outputs[ours[0]]
        if stage == "fusion":
            same = float(np.mean(np.asarray(a.weight) == np.asarray(b.weight)))
            gap = np.abs(np.asarray(a.values) - np.asarray(b.values))
            agreement = (f"weights equal {same:.6f}; values: {np.mean(gap > 1e-4):.2e} of voxels differ by > 1e-4 "
                         f"(a voxel projected to a neighbouring pixel), at most {gap.max():.2g}")
        else:
            real = np.isfinite(np.asarray(a, np.float32))
            diff = float(np.max(np.abs(np.asarray(a, np.float32) - np.asarray(b, np.float32))[real]))
            agreement = f"within {diff:.2g}"
        base = statistics.median(times[reference[0]])
        for name in (reference[0], ours[0]):
            ms = statistics.median(times[name])
            rows.append((stage, name, report.device_name(), args.batch, f"{ms:.2f}",
                         f"{min(times[name]):.2f}-{max(times[name]):.2f}", f"{base / ms:.2f}x",
                         agreement if name == ours[0] else "-"))
    report.publish(report.section(
        "The move's Pallas kernels against XLA's", argv,
        ("stage", "program", "device", "batch", "median ms a call", "range", "speed-up", "agreement"), rows,
        intro=f"{args.repeats} calls of each, in turns (``report.interleaved``), after a compiling call."), args.out)


if __name__ == "__main__":
    main()
