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
(F1 of the target objects pooled over scenes, macro over classes, 95% scene-bootstrap intervals). The logic
is ``jaxcls.experiments.fused_views``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from jaxcls import compile_cache, io, report
from jaxcls.config import load_config
from jaxcls.episode import protocol
from jaxcls.experiments import fused_views
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.experiments.table1.data import open_dataset
from jaxcls.world.objects import object_set_from_config


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
    config = load_config(Table1Config, args.config, args.overrides)
    dataset, files = open_dataset(config)
    classes = len(object_set_from_config(dataset.objects).classes)
    row = protocol.row(args.row, "--row")
    V = dataset.viewpoints.count
    records = fused_views.run(config, dataset, files, args.views, args.subsets, row, args.passes,
                              Path(config.out_dir) / "fused_views.jsonl")
    tracked = (f"tracked, {args.passes} pass{'es' if args.passes > 1 else ''}" if config.perception.tracking.on
               else "as given")
    markdown = (f"### {row.label} against the views fused on `{config.dataset}`\n\n`{report.command_line(argv)}`\n\n"
                f"{len(files)} scenes, {args.subsets} random view subsets per scene and k (one when k is every "
                "view); F1 of the target objects, pooled over scenes, 95% scene-bootstrap interval.\n\n"
                + fused_views.f1_table(records, config.classifiers, args.views, V, len(files), classes,
                                       config.resamples) + "\n\n"
                f"Pose error of the frames fused ({tracked}; "
                "median / 95th percentile over frames and scenes), the displacement of the scene's centre and "
                "the rotation:\n\n" + fused_views.error_table(records, config.classifiers, args.views, V) + "\n")
    io.write_text(Path(config.out_dir) / "fused_views.md", markdown)
    report.publish(markdown, args.out)


if __name__ == "__main__":
    main()
