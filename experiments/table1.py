"""The paper's Table 1 and Figure 4: every row's episodes on a dataset's scenes, with confidence intervals.

    python experiments/table1.py --config table1_synthetic [key=value ...] [--out RESULTS.md]
    python experiments/table1.py --config table1_real_like

The scenes are a ``jaxcls dataset`` (``dataset``: a shipped dataset config name, a config path, or a folder
written by ``jaxcls dataset``; a config's folder is rendered first if it is missing or incomplete, and
``dataset_overrides`` change it, e.g. ``[num_scenes=30,out_dir=data/synthetic_30]``); with
``scene_source=device`` the config's scenes are drawn with its seeds and rendered chunk by chunk where the
episodes run (the scene bank on a GPU, MuJoCo's C caster on a CPU), nothing written. The rows are
``protocol.ROWS`` names (``rows``); each runs ``runs`` episodes per scene from seeded random start views
(the same starts and keys for every row: rows are paired), ``moves`` moves each, with every classifier of
``classifiers`` (name: a ``.msgpack`` path or a shipped name, "" = the shipped weights). The oracle row
runs on the first ``oracle_scenes`` scenes only (it tries every candidate at every move), a scene's runs
together on an accelerator (``oracle_runs_per_call``). On a GPU, float32 products run at full precision
(``jaxcls.precision``).

Episodes stream to ``out_dir/episodes.jsonl`` as each scene's runs of a row finish; running the command
again skips what is there (an interrupted run resumes without redoing or losing an episode; a torn last
line is dropped). Same config, same numbers. Outputs in ``out_dir``: ``table.md`` (the table laid out as the
paper's, per classifier, then the paired differences and moves-to-correct), ``table.csv`` (every row x
move), ``figure4.png`` (F1 over moves, with 95% bands), ``timing.json`` (each module's time per move).

This is the command line; the logic is ``jaxcls.experiments.table1`` (``config``, ``data``, ``runner``,
``scoring``, ``tables``, ``figure``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from jaxcls import compile_cache, io, precision, report
from jaxcls.config import load_config, save_config
from jaxcls.experiments.table1 import data, figure, runner, tables
from jaxcls.experiments.table1.config import Table1Config, check_out_dir
from jaxcls.world.objects import object_set_from_config


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="table1_synthetic", help="a path or a shipped config name")
    parser.add_argument("--out", help="append the tables to this Markdown file")
    parser.add_argument("--tables-only", action="store_true",
                        help="only the tables of the episodes stored in out_dir (none run, no scene file read)")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_intermixed_args(argv)
    # No allocator.retain_freed_memory() here: batched episodes gain little from it.
    precision.full_float32_matmuls()  # no TF32 on a GPU (jaxcls.precision)
    compile_cache.enable()  # the row programs kept on disk for the next run (jaxcls.compile_cache)
    config = load_config(Table1Config, args.config, args.overrides)
    out = Path(config.out_dir)
    check_out_dir(config, out)
    started = time.perf_counter()
    timing_file = out / "timing.json"
    timing = json.loads(timing_file.read_text()) if timing_file.exists() else None
    if args.tables_only:
        dataset = data.dataset_config(config)
        records = data.stored_records(config, out / "episodes.jsonl")
    else:
        dataset, scene_set = data.open_scenes(config)
        save_config(config, out / "config.yaml")
        records = runner.run_episodes(config, scene_set, dataset, out / "episodes.jsonl")
    if timing is None and config.timing_moves and not args.tables_only:
        timing = runner.time_modules(config, scene_set, dataset)
        io.write_json(timing_file, timing)
    classes = len(object_set_from_config(dataset.objects).classes)
    markdown, csv_rows, curves = tables.tables(config, records, classes, timing, argv)
    io.write_text(out / "table.md", markdown)
    io.write_text(out / "table.csv", tables.csv_text(csv_rows))
    if curves:
        figure.figure4(curves, out / "figure4.png")
    print(f"{len(records)} episodes in {out} ({time.perf_counter() - started:.0f} s this run)", file=sys.stderr)
    report.publish(markdown, args.out)


if __name__ == "__main__":
    main()
