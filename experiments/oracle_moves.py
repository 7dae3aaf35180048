"""Where an oracle row of Table 1 makes its lead: every row's F1 after each move on the oracle's scenes, and each
row's paired gain in its last move (F1 at T - F1 at T - 1, scene bootstrap).

    python experiments/oracle_moves.py \\
        --config results/learned_policy_2026-11-29/rollout_labels/table1_real_like_paper/config.yaml [--out FILE]

``--config`` is a Table 1 run's config (its ``out_dir`` holds the stored episodes, ``episodes.jsonl`` or its
``.xz`` archive). The rows are compared on the scenes every oracle row of the config ran (its first
``oracle_scenes``), the same starts and keys. An oracle that picks its last view by the true classes gains there
what no policy without the truth can (RESULTS.md, "The learned view policy").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from jaxcls import metrics, report
from jaxcls.config import load_config
from jaxcls.episode import protocol
from jaxcls.experiments.table1 import data
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.world.objects import object_set_from_config


def tables(config: Table1Config, records: list[dict], classes: int) -> str:
    """Markdown: per classifier, every row's F1 after each move and its paired last-move gain, on the scenes
    of the oracle rows (all scenes where there is none)."""
    T, lines = config.moves, []
    for c in config.classifiers:
        rows = [n for n in config.rows if any(r["classifier"] == c and r["row"] == n for r in records)]
        oracles = [n for n in rows if protocol.ROWS[n].kind is protocol.Kind.ORACLE]
        scenes = set.intersection(*({r["scene"] for r in records if r["classifier"] == c and r["row"] == n}
                                    for n in (oracles or rows)))
        lines += [f"#### Classifier `{c}`: {len(scenes)} scenes", "",
                  "| row | " + " | ".join(str(t) for t in range(1, T + 1)) + f" | move {T - 1} -> {T}, paired |",
                  "| --- | " + " | ".join("---" for _ in range(T)) + " | --- |"]
        for n in rows:
            labels = protocol.scene_labels([r for r in records if r["classifier"] == c and r["row"] == n
                                            and r["scene"] in scenes])
            f1 = [metrics.classification_scores(*map(np.concatenate, zip(*labels.at(t), strict=True)), classes).f1
                  for t in range(1, T + 1)]
            gain = metrics.paired_difference(labels.at(T), labels.at(T - 1), classes, resamples=config.resamples)
            lines.append(f"| {protocol.ROWS[n].label} | " + " | ".join(f"{x:.3f}" for x in f1)
                         + f" | {metrics.format_difference(*gain)} |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True, help="a Table 1 run's config.yaml")
    parser.add_argument("--out", help="append the tables to this Markdown file")
    args = parser.parse_args(argv)
    config = load_config(Table1Config, args.config)
    if config.moves < 2:
        parser.error(f"{args.config}: moves = {config.moves}; a last-move gain needs 2 or more")
    records = data.stored_records(config, Path(config.out_dir) / "episodes.jsonl")
    if not records:
        parser.error(f"{config.out_dir}: no stored episodes of this config (episodes.jsonl or its .xz archive)")
    classes = len(object_set_from_config(data.dataset_config(config).objects).classes)
    report.publish(tables(config, records, classes), args.out)


if __name__ == "__main__":
    main()
