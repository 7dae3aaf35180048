"""Segmentation speed: one move's chain (foreground, integration, extraction, segmentation), CPU and GPU.

The CPU times it stage by stage and as ``perception.observe``; a GPU, batched over fused clouds.

    python benchmarks/segment.py                                  # prints the Markdown section
    python benchmarks/segment.py --out BENCHMARKS.md

Scenes: the builtin set's (``jaxcls.experiments.segmentation``: ``mujoco`` depth at five hemisphere views from
low to high elevation, fused into the default 0.6 m / 128^3 volume). The CPU rows time the stages ``observe``
composes one by one, then ``observe`` itself, on the 5th view of ``synthetic`` scene 0 after four fused; the GPU
rows batch the 5-view surfaces of ``--seeds`` scenes per kind. The segmentation quality of the same scenes is
``experiments/segmentation.py``'s (it was this script's ``--out-results`` section).
"""

from __future__ import annotations

import argparse
import datetime
import sys

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import perception, report
from jaxcls.experiments.segmentation import KINDS, VIEWS, fused, render_scene
from jaxcls.geometry import Intrinsics
from jaxcls.perception import foreground, segment, tsdf


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12, help="scenes per kind (seeds 0..n-1) for the GPU batch")
    parser.add_argument("--scale", type=float, default=1.0, help="image scale of the Kinect v1 (1 = 640x480)")
    parser.add_argument("--max-points", type=int, default=16384, help="static size of the extracted surface")
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--gpu-batch", type=int, nargs="*", default=[64, 256])
    parser.add_argument("--out", help="append the speed section to this Markdown file")
    parser.add_argument("--out-results", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.out_results:
        parser.error("--out-results: the quality table is experiments/segmentation.py's now "
                     f"(python experiments/segmentation.py --seeds {args.seeds} --out {args.out_results})")
    settings = perception.PerceptionConfig(shapes=perception.ShapeConfig(surface_points=args.max_points))
    intr = Intrinsics.kinect_v1(args.scale)
    res = f"{intr.width}x{intr.height}"
    cpu_device = jax.devices("cpu")[0]
    cpu = report.cpu_name()
    observe = jax.jit(perception.perceive)  # one move: foreground, integration, extraction, `segment_jax`

    def spec_of(world) -> perception.Spec:
        return perception.Spec.create(settings, world.intrinsics, world.table_height)

    rows: list[tuple[str, ...]] = []
    with jax.default_device(cpu_device):
        world, depth, Ts, _ = render_scene("synthetic", 0, args.scale)
        spec = spec_of(world)
        state = perception.init_state(spec)
        for v in range(len(VIEWS) - 1):
            state = observe(spec, state, jnp.asarray(depth[v]), jnp.asarray(Ts[v]))
        volume = state.volume
        d, T = jnp.asarray(depth[-1]), jnp.asarray(Ts[-1])
        # Each stage on its own (measuring, not wiring): the functions `observe` composes.
        integrate = jax.jit(lambda vol, d, T: tsdf.integrate(vol, d, spec.intrinsics, T))
        extract = jax.jit(lambda vol: tsdf.extract_surface(vol, args.max_points))
        steps = {
            "foreground (`foreground_depth`)": lambda: foreground.foreground_depth(spec, d, T),
            "integration (`integrate`)": lambda: integrate(volume, foreground.foreground_depth(spec, d, T), T),
            f"extraction (`extract_surface`, {args.max_points} points)": lambda: extract(volume),
        }
        surf = extract(integrate(volume, foreground.foreground_depth(spec, d, T), T))
        steps["segmentation, reference (`segment`: scikit-learn DBSCAN + SciPy)"] = lambda: segment.segment(
            spec, surf.points, surf.normals, surf.mask)
        steps["segmentation, JAX twin (`segment_jax`)"] = lambda: segment.segment_jax(
            spec, surf.points, surf.normals, surf.mask)
        steps["one move: foreground + integration + extraction + `segment_jax`"] = lambda: observe(spec, state, d, T)
        for name, fn in steps.items():
            first, med, _ = report.timed(fn, args.repeats)
            rows.append((name, cpu, f"{med * 1e3:.1f}", f"{first * 1e3:.0f}", ""))
            print(rows[-1], file=sys.stderr)

    notes = []
    if jax.default_backend() == "gpu":
        clouds = []  # fused 5-view surfaces of every scene, for the GPU batch
        with jax.default_device(cpu_device):
            for kind in KINDS:
                for seed in range(args.seeds):
                    surface = fused(kind, seed, args.scale, settings, observe)[3][len(VIEWS)].surface
                    clouds.append(tuple(np.asarray(a) for a in (surface.points, surface.normals, surface.mask)))
        gpu = f"GPU ({jax.devices()[0].device_kind})"
        batched_seg = jax.jit(jax.vmap(segment.segment_jax, in_axes=(None, 0, 0, 0)))
        batched_move = jax.jit(jax.vmap(perception.perceive, in_axes=(None, 0, 0, 0)))
        for batch in args.gpu_batch:
            pick = [clouds[i % len(clouds)] for i in range(batch)]
            p, n, m = (jnp.asarray(np.stack(a)) for a in zip(*pick, strict=True))
            first, med, _ = report.timed(lambda p=p, n=n, m=m: batched_seg(spec, p, n, m), args.repeats)
            rows.append((f"`segment_jax`, vmap over {batch} fused clouds", gpu, f"{med * 1e3:.2f}",
                         f"{first * 1e3:.0f}", f"{batch / med:.0f} segmentations/s"))
            print(rows[-1], file=sys.stderr)
            states = jax.tree.map(lambda x, b=batch: jnp.broadcast_to(x, (b, *x.shape)), jax.device_put(state))
            ds = jnp.broadcast_to(jnp.asarray(depth[-1]), (batch, *depth.shape[1:]))
            Tb = jnp.broadcast_to(jnp.asarray(Ts[-1]), (batch, 4, 4))
            try:
                first, med, _ = report.timed(lambda s=states, d=ds, T=Tb: batched_move(spec, s, d, T), args.repeats)
            except jax.errors.JaxRuntimeError as error:  # out of GPU memory: keep the rows measured so far
                notes.append(f"one move, vmap over {batch}: {str(error).splitlines()[0][:120]}")
                continue
            rows.append((f"one move (foreground + integration + extraction + `segment_jax`), vmap over {batch}",
                         gpu, f"{med * 1e3:.2f}", f"{first * 1e3:.0f}", f"{batch / med:.0f} moves/s"))
            print(rows[-1], file=sys.stderr)
    else:
        notes.append("GPU rows skipped: JAX sees no GPU")
    report.publish(report.section(
        f"Segmentation speed, {res} depth, 128^3 volume, {datetime.date.today()}", argv,
        ("operation", "device", f"median ms ({args.repeats} calls)", "first call ms", "notes"), rows, notes=notes),
        args.out)


if __name__ == "__main__":
    main()
