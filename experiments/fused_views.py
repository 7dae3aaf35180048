"""PointNetFull against the number of views fused, with the camera poses the sensor reports and the true ones.

    python experiments/fused_views.py --config table1_real_like [key=value ...] [--views 1 4 11 33 100]
        [--subsets 3] [--row full_gr] [--out RESULTS.md]

Table 1's PointNetFull fuses every viewpoint of a scene and is meant as the upper bound of any policy. On
the real-like set it scores below the active policies. This experiment asks why: for each scene it fuses
``subsets`` seeded random subsets of k views (one subset when k is every view) and runs the row's last
move (segmentation, classification, GR) on them, once with the poses the episodes see (``T_wc``: the
true poses times the sequence's hand-eye calibration error, ``sensor.pose_noise``) and once with the
true poses (``T_wc_true``). If F1 with the true poses grows with k while F1 with the reported poses does
not, the views' misregistration is what costs PointNetFull.

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
from tqdm.auto import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
import table1

from jaxcls import io, report
from jaxcls.config import load_config
from jaxcls.episode import protocol, scoring, setup, sources
from jaxcls.world.objects import object_set_from_config

POSES = ("reported", "true")


def subset(seed: int, scene: int, k: int, index: int, num_views: int) -> np.ndarray:
    """[k] distinct views of a scene, seeded by (seed, scene, k, index); every view, in order, if k >= V."""
    if k >= num_views:
        return np.arange(num_views)
    return np.random.default_rng([seed, scene, k, index]).choice(num_views, size=k, replace=False)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="table1_real_like", help="a Table 1 config (path or shipped name)")
    parser.add_argument("--views", type=int, nargs="+", default=[1, 4, 11, 33, 100], help="views fused, k")
    parser.add_argument("--subsets", type=int, default=3, help="random subsets per scene and k < V")
    parser.add_argument("--row", default="full_gr", choices=["full", "full_gr"])
    parser.add_argument("--out", help="append the table to this Markdown file")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_intermixed_args(argv)
    if min(args.views) < 1 or args.subsets < 1:
        raise ValueError(f"--views must be >= 1 and --subsets >= 1 (got {args.views}, {args.subsets})")
    config = load_config(table1.Table1Config, args.config, args.overrides)
    dataset, files = table1.open_dataset(config)
    object_set = object_set_from_config(dataset.objects)
    classes = len(object_set.classes)
    classifiers = {name: setup.load_classifier(path, object_set, f"classifiers.{name}")
                   for name, path in config.classifiers.items()}
    row = protocol.row(args.row, "--row")
    store = Path(config.out_dir) / "fused_views.jsonl"

    def key(r):
        return r["classifier"], r["poses"], int(r["views"]), int(r["scene"]), int(r["subset"])

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
                            record_key = (c, pose, min(k, V), s, i)
                            bar.update()
                            if record_key in done:
                                continue
                            trace = protocol.all_views(episodes[c], views.depth[chosen], poses[pose][chosen],
                                                       episode_key)
                            record = protocol.episode_record(jax.device_get(trace), truth, classifier=c, poses=pose,
                                                             views=min(k, V), scene=s, subset=i, run=0, start=-1)
                            io.append_jsonl(store, [record])
    records = list(io.read_jsonl(store))
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
                + report.table(("classifier", "camera poses", *(f"k = {k}" for k in args.views)), table_rows) + "\n")
    io.write_text(Path(config.out_dir) / "fused_views.md", markdown)
    report.publish(markdown, args.out)


if __name__ == "__main__":
    main()
