"""Segmentation quality and speed: both paths on fused scenes, scored against the posed object surfaces, and
one move's chain (foreground, integration, extraction, segmentation) timed on the CPU and, batched, on a GPU.

    python benchmarks/segment.py                                  # prints the Markdown sections
    python benchmarks/segment.py --out-results RESULTS.md --out BENCHMARKS.md

Scenes: the builtin set, ``synthetic`` (footprint gaps 3 mm - 3 cm) and ``touching`` (1-5 mm), depth from
the ``mujoco`` backend at five hemisphere views from low to high elevation, fused into the default 0.6 m /
128^3 volume. A surface point's ground truth is its nearest posed object surface; points more than 1 cm
from every object are left out. "agreement" is the adjusted Rand index between the two paths' labels.
Worlds come from ``make_world``; each frame goes through ``perception.observe`` (jitted: the JAX twin's
move), whose surface the reference path segments too. The speed rows time the stages ``observe``
composes one by one, then ``observe`` itself.
"""

from __future__ import annotations

import argparse
import datetime
import sys

import jax
import jax.numpy as jnp
import numpy as np
from sklearn.metrics import adjusted_rand_score

from jaxcls import metrics, perception, report
from jaxcls.geometry import CameraConfig, Intrinsics
from jaxcls.perception import foreground, segment, tsdf
from jaxcls.world import WorldConfig, make_world, scenes

VIEWS = (20, 35, 50, 65, 80)
KINDS = {"synthetic": scenes.SceneConfig(), "touching": scenes.SceneConfig(min_gap=0.001, max_gap=0.005)}


def render_scene(kind: str, seed: int, scale: float):
    """(world, depth [V, H, W], T_wc [V, 4, 4], ground-truth function of points) of one scene at ``VIEWS``."""
    world = make_world(WorldConfig(scene=KINDS[kind], camera=CameraConfig.kinect_v1(scale), backend="mujoco"), seed)
    depth = world.render(list(VIEWS)).depth
    truth = metrics.PointOwners(world.scene, world.models)  # nearest posed object within 1 cm, else -1
    return world, np.asarray(depth), np.asarray(world.poses(list(VIEWS)), np.float32), truth


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12, help="scenes per kind (seeds 0..n-1)")
    parser.add_argument("--scale", type=float, default=1.0, help="image scale of the Kinect v1 (1 = 640x480)")
    parser.add_argument("--max-points", type=int, default=16384, help="static size of the extracted surface")
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--gpu-batch", type=int, nargs="*", default=[64, 256])
    parser.add_argument("--out", help="append the speed section to this Markdown file")
    parser.add_argument("--out-results", help="append the quality section to this Markdown file")
    args = parser.parse_args(argv)
    settings = perception.PerceptionConfig(shapes=perception.ShapeConfig(surface_points=args.max_points))
    intr = Intrinsics.kinect_v1(args.scale)
    res = f"{intr.width}x{intr.height}"
    cpu_device = jax.devices("cpu")[0]
    cpu = report.cpu_name()
    observe = jax.jit(perception.observe)  # one move: foreground, integration, extraction, `segment_jax`

    def spec_of(world) -> perception.Spec:
        return perception.Spec.create(settings, world.intrinsics, world.table_height)

    scores: dict[tuple[str, int, str], list[float]] = {}
    clouds = []  # fused 5-view surfaces, for the GPU batch
    with jax.default_device(cpu_device):
        for kind in KINDS:
            for seed in range(args.seeds):
                world, depth, Ts, truth = render_scene(kind, seed, args.scale)
                spec = spec_of(world)
                state = perception.init_state(spec)
                for v in range(len(VIEWS)):
                    state = observe(spec, state, jnp.asarray(depth[v]), jnp.asarray(Ts[v]))
                    if v + 1 not in (1, 5):
                        continue
                    s = state.surface
                    p, n, m = np.asarray(s.points), np.asarray(s.normals), np.asarray(s.mask)
                    gt = truth(p, m)
                    ref = np.asarray(segment.segment(spec, p, n, m).labels)
                    twin = np.asarray(state.segments.labels)
                    sel, either = gt >= 0, (ref >= 0) | (twin >= 0)
                    scores.setdefault((kind, v + 1, "reference"), []).append(adjusted_rand_score(gt[sel], ref[sel]))
                    scores.setdefault((kind, v + 1, "jax"), []).append(adjusted_rand_score(gt[sel], twin[sel]))
                    scores.setdefault((kind, v + 1, "agreement"), []).append(adjusted_rand_score(ref[either],
                                                                                                 twin[either]))
                    if v + 1 == 5:
                        clouds.append((p, n, m))
                print(kind, seed, {k: round(x[-1], 3) for k, x in scores.items() if k[0] == kind}, file=sys.stderr)
    quality = [(kind, views, what, f"{np.mean(v):.3f}", f"{np.min(v):.3f}", " ".join(f"{x:.2f}" for x in v))
               for (kind, views, what), v in sorted(scores.items(), key=lambda kv: (kv[0][0], kv[0][1]))]
    report.publish(report.section(
        f"Segmentation quality, {res} depth fused into 128^3, {args.seeds} scenes per kind, "
        f"{datetime.date.today()}", argv, ("scenes", "views", "path", "mean ARI", "min ARI", "per scene"),
        quality, intro="ARI against the posed object surfaces; `agreement` is the twin against the reference."),
        args.out_results)

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
        gpu = f"GPU ({jax.devices()[0].device_kind})"
        batched_seg = jax.jit(jax.vmap(segment.segment_jax, in_axes=(None, 0, 0, 0)))
        batched_move = jax.jit(jax.vmap(perception.observe, in_axes=(None, 0, 0, 0)))
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
