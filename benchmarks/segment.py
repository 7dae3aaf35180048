"""Segmentation speed and agreement: the reference path (scikit-learn) on a fused 5-object scene, and the
fusion + extraction + segmentation chain, with adjusted Rand indices against the posed object surfaces.

    python benchmarks/segment.py                      # prints a Markdown table
    python benchmarks/segment.py --out BENCHMARKS.md  # also appends it

The JAX twin (``segment_jax``) is not written yet: its rows are missing.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial import cKDTree
from sklearn.metrics import adjusted_rand_score

from jaxcls import report, scenes, segment, tsdf
from jaxcls.assets import builtin_object_set
from jaxcls.geometry import Intrinsics, hemisphere_viewpoints
from jaxcls.render import make_renderer

VIEWS = (20, 35, 50, 65, 80)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--scale", type=float, default=1.0, help="image scale of the Kinect v1 (1 = 640x480)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    cfg = segment.SegmentConfig()
    intr = Intrinsics.kinect_v1(args.scale)
    object_set = builtin_object_set()
    rows, ari = [], {}
    touching = scenes.SceneConfig(min_gap=0.001, max_gap=0.005)
    for kind, sc in (("synthetic", scenes.SceneConfig()), ("touching", touching)):
        for seed in args.seeds:
            scene = scenes.sample_scene(object_set, sc, seed)
            models = scenes.scene_models(scene, object_set)
            Ts = hemisphere_viewpoints(scenes.scene_centroid(scene, models), 100)[list(VIEWS)]
            fr = make_renderer(scenes.build_model(scene, models, intr), intr, "mujoco").render(Ts)
            samples = [(T[:3, :3] @ m.surface_points.T).T + T[:3, 3]
                       for m, T in zip(models, scene.object_poses(), strict=True)]
            allp, owner = np.concatenate(samples), np.concatenate([np.full(len(s), i) for i, s in enumerate(samples)])
            tree = cKDTree(allp)
            T32 = jnp.asarray(Ts, jnp.float32)

            def chain(n_views: int, T32=T32, fr=fr):
                vol = tsdf.create_volume(np.asarray(cfg.roi_center), cfg.roi_size, 128)
                for d, T in zip(fr.depth[:n_views], T32[:n_views], strict=True):
                    vol = tsdf.integrate(vol, segment.foreground_depth(jnp.asarray(d), intr, T, cfg), intr, T)
                s = tsdf.extract_surface(vol, 32768)
                return s, segment.segment(s.points, s.normals, s.mask, cfg)

            for n_views in (1, 5):
                surf, seg = chain(n_views)
                p, m = np.asarray(surf.points), np.asarray(surf.mask)
                dist, idx = tree.query(p)
                gt = np.where(m & (dist < 0.01), owner[idx], -1)
                ari.setdefault((kind, n_views), []).append(
                    adjusted_rand_score(gt[gt >= 0], np.asarray(seg.labels)[gt >= 0]))
            if kind == "synthetic" and seed == args.seeds[0]:
                times, seg_times = [], []
                for _ in range(args.repeats):
                    t0 = time.perf_counter()
                    surf, _ = chain(5)
                    times.append(time.perf_counter() - t0)
                    t0 = time.perf_counter()
                    segment.segment(surf.points, surf.normals, surf.mask, cfg)
                    seg_times.append(time.perf_counter() - t0)
    cpu = f"CPU ({platform.processor() or platform.machine()}, {os.cpu_count()} cores)"
    rows.append(("reference `segment` (sklearn DBSCAN + footprint cores + K-means), fused 5 views", cpu,
                 f"{statistics.median(seg_times) * 1e3:.0f}"))
    rows.append(("5 x (foreground + integrate) + extract + reference segment", cpu,
                 f"{statistics.median(times) * 1e3:.0f}"))
    cmd = report.command_line(argv)
    lines = [f"## Segmentation ({intr.width}x{intr.height}, jax {jax.__version__})", "", f"`{cmd}`", "",
             "| what | device | median ms |", "|---|---|---|"]
    lines += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    lines += ["", "| ARI vs posed surfaces (reference path) | seeds | min | mean |", "|---|---|---|---|"]
    for (kind, n), v in sorted(ari.items()):
        lines.append(f"| {kind}, {n} view(s) | {args.seeds} | {min(v):.3f} | {np.mean(v):.3f} |")
    lines += ["", "JAX twin rows: not implemented yet."]
    text = "\n".join(lines) + "\n"
    report.publish(text, args.out)


if __name__ == "__main__":
    main()
