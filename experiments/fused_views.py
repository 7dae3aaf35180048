"""PointNetFull against the number of views fused, with the camera poses the sensor reports and the true ones.

    python experiments/fused_views.py --config table1_real_like [key=value ...] [--views 1 4 11 33 100]
        [--subsets 3] [--row full_gr] [--passes 2] [--out RESULTS.md]

Table 1's PointNetFull fuses every viewpoint of a scene and is meant as the upper bound of any policy. On
the real-like set it scores below the active policies. This experiment asks why: for each scene it fuses
``subsets`` seeded random subsets of k views (one subset when k is every view) and runs the row's last
move (segmentation, classification, GR) on them, once with the poses the episodes see (``T_wc``: the
true poses times the sequence's hand-eye calibration error, ``sensor.pose_noise``) and once with the
true poses (``T_wc_true``). If F1 with the true poses grows with k while F1 with the reported poses does
not, the views' misregistration is what costs PointNetFull. With tracking on, the views are fused
``--passes`` times (``protocol.all_views``: each pass with the hand-eye estimate the previous one ended with).

The scenes, classifiers and move settings are a Table 1 config's (``experiments/table1.py``). Records
stream to ``out_dir/fused_views.jsonl`` and a rerun resumes; ``out_dir/fused_views.md`` holds the table
(F1 of the target objects pooled over scenes, macro over classes, 95% scene-bootstrap intervals).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import numpy as np
from scipy.spatial.transform import Rotation
from tqdm.auto import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
import table1

from jaxcls import compile_cache, io, report
from jaxcls.config import load_config
from jaxcls.episode import protocol, scoring, setup, sources
from jaxcls.world.objects import object_set_from_config

POSES = ("reported", "true")


def subset(seed: int, scene: int, k: int, index: int, num_views: int) -> np.ndarray:
    """[k] distinct views of a scene, seeded by (seed, scene, k, index); every view, in order, if k >= V."""
    if k >= num_views:
        return np.arange(num_views)
    return np.random.default_rng([seed, scene, k, index]).choice(num_views, size=k, replace=False)


def pose_errors(fused: np.ndarray, true: np.ndarray, table_height: float) -> dict[str, list[float]]:
    """Each frame's pose error (fused [K, 4, 4] against true [K, 4, 4] T_wc), rounded for the record:
    translation_mm, how far the frame's error G = fused @ true^-1 moves the scene's centre (5 cm above the
    table's centre: where the objects are, so a rotation about the camera counts by its lever arm);
    rotation_deg, G's angle; relative_mm, the same displacement after the frames' mean error is removed (what
    blurs the fused model: a common offset of every frame moves the model but does not blur it)."""
    centre = np.array([0.0, 0.0, table_height + 0.05, 1.0])
    G = np.asarray(fused, np.float64) @ np.linalg.inv(np.asarray(true, np.float64))
    moved = (G @ centre)[:, :3] - centre[:3]
    rotation = np.degrees(Rotation.from_matrix(G[:, :3, :3]).magnitude())
    relative = np.linalg.norm(moved - moved.mean(axis=0), axis=1)
    return {"translation_mm": np.round(np.linalg.norm(moved, axis=1) * 1e3, 3).tolist(),
            "rotation_deg": np.round(rotation, 4).tolist(), "relative_mm": np.round(relative * 1e3, 3).tolist()}


def error_table(records: list[dict], classifiers, views: list[int], num_views: int) -> str:
    """Median and 95th percentile of the frames' pose errors (``pose_errors``) per camera-pose source and k."""
    rows = []
    c = next(iter(classifiers))
    for pose in POSES:
        for name, unit in (("translation_mm", "mm"), ("relative_mm", "mm, mean removed"), ("rotation_deg", "deg")):
            cells = []
            for k in views:
                values = np.concatenate([r["pose_error"][name] for r in records if "pose_error" in r
                                         and r["classifier"] == c and r["poses"] == pose
                                         and r["views"] == min(k, num_views)] or [[np.nan]])
                cells.append(f"{np.median(values):.2f} / {np.percentile(values, 95):.2f}")
            rows.append((pose, f"{name.split('_')[0]} ({unit})", *cells))
    return report.table(("camera poses", "error", *(f"k = {k}" for k in views)), rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="table1_real_like", help="a Table 1 config (path or shipped name)")
    parser.add_argument("--views", type=int, nargs="+", default=[1, 4, 11, 33, 100], help="views fused, k")
    parser.add_argument("--subsets", type=int, default=3, help="random subsets per scene and k < V")
    parser.add_argument("--row", default="full_gr", choices=["full", "full_gr"])
    parser.add_argument("--passes", type=int, default=2, help="fusion passes with tracking (protocol.all_views)")
    parser.add_argument("--out", help="append the table to this Markdown file")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_intermixed_args(argv)
    if min(args.views) < 1 or args.subsets < 1 or args.passes < 1:
        raise ValueError(f"--views, --subsets and --passes must be >= 1 (got {args.views}, {args.subsets}, "
                         f"{args.passes})")
    compile_cache.enable()  # compiled programs kept on disk for the next run (jaxcls.compile_cache)
    config = load_config(table1.Table1Config, args.config, args.overrides)
    dataset, files = table1.open_dataset(config)
    object_set = object_set_from_config(dataset.objects)
    classes = len(object_set.classes)
    classifiers = {name: setup.load_classifier(path, object_set, f"classifiers.{name}")
                   for name, path in config.classifiers.items()}
    row = protocol.row(args.row, "--row")
    store = Path(config.out_dir) / "fused_views.jsonl"

    def key(r):
        return r["classifier"], r["poses"], int(r["views"]), int(r["scene"]), int(r["subset"]), r.get("passes", 1)

    done = {key(r) for r in io.read_jsonl(store)}
    episodes = {}
    V = dataset.viewpoints.count
    total = len(files) * len(classifiers) * len(POSES) * sum(1 if k >= V else args.subsets for k in args.views)
    with tqdm(total=total, desc="fused views", unit="episode") as bar:
        for s, path in enumerate(files):
            views = sources.dataset_source(path, dataset.objects)
            with np.load(path) as scene:
                poses = {"reported": np.asarray(views.T_wc), "true": scene["T_wc_true"]}
            truth = scoring.Truth.from_scene(views.scene, object_set)
            episode_key = protocol.run_keys(config.seed, s, 1)[0]
            for c, classifier in classifiers.items():
                if c not in episodes:
                    episodes[c] = table1._episode(config, row, classifier, object_set, views, dataset.scene.split)
                for k in args.views:
                    for i in range(1 if k >= V else args.subsets):
                        chosen = subset(config.seed, s, k, i, V)
                        for pose in POSES:
                            record_key = (c, pose, min(k, V), s, i, args.passes)
                            bar.update()
                            if record_key in done:
                                continue
                            trace, fused = protocol.all_views(episodes[c], views.depth[chosen], poses[pose][chosen],
                                                              episode_key, args.passes)
                            order = np.concatenate([chosen[1:], chosen[:1]])  # all_views fuses view 0 last
                            record = protocol.episode_record(jax.device_get(trace), truth, classifier=c, poses=pose,
                                                             views=min(k, V), scene=s, subset=i, run=0, start=-1,
                                                             passes=args.passes)
                            record["pose_error"] = pose_errors(np.asarray(fused), poses["true"][order],
                                                               views.table_height)
                            io.append_jsonl(store, [record])
    records = [r for r in io.read_jsonl(store) if r.get("passes", 1) == args.passes]
    tracked = (f"tracked, {args.passes} pass{'es' if args.passes > 1 else ''}" if config.perception.tracking.on
               else "as given")
    table_rows = []
    for c in classifiers:
        for pose in POSES:
            cells = []
            for k in args.views:
                recs = [r for r in records if r["classifier"] == c and r["poses"] == pose
                        and r["views"] == min(k, V) and r["scene"] < len(files)]
                sc = table1.row_scores(recs, classes, 1, config.resamples)
                cells.append(f"{sc['f1']:.3f} [{sc['f1_low']:.3f}, {sc['f1_high']:.3f}]")
            table_rows.append((c, pose, *cells))
    markdown = (f"### {row.label} against the views fused on `{config.dataset}`\n\n`{report.command_line(argv)}`\n\n"
                f"{len(files)} scenes, {args.subsets} random view subsets per scene and k (one when k is every "
                "view); F1 of the target objects, pooled over scenes, 95% scene-bootstrap interval.\n\n"
                + report.table(("classifier", "camera poses", *(f"k = {k}" for k in args.views)), table_rows) + "\n\n"
                f"Pose error of the frames fused ({tracked}; "
                "median / 95th percentile over frames and scenes), the displacement of the scene's centre and "
                "the rotation:\n\n" + error_table(records, classifiers, args.views, V) + "\n")
    io.write_text(Path(config.out_dir) / "fused_views.md", markdown)
    report.publish(markdown, args.out)


if __name__ == "__main__":
    main()
