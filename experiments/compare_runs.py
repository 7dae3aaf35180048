"""One row of two Table 1 runs on the same scenes, paired: an A/B of two settings that one run cannot hold both of
(two policy weights in ``learned_gr``, say), with each run's oracle rows for the share of the gap.

    python experiments/compare_runs.py \\
        --a results/learned_policy_2026-11-29/rollout_labels/table1_real_like_paper_fair/config.yaml \\
        --b results/learned_policy_2026-11-29/rollout_labels/table1_real_like_paper_ppo/config.yaml \\
        [--row learned_gr] [--reference info_gain_gr] [--out FILE]

``--a`` / ``--b`` are Table 1 runs' configs (their ``out_dir`` holds the stored episodes, ``episodes.jsonl`` or its
``.xz`` archive). The two runs must have drawn the same scenes, starts and keys: the ``--reference`` row, which both
ran with the same settings, must have the same path and labels in every episode both hold, else the runs are
refused. Then, per classifier: ``row`` of B - ``row`` of A on their common scenes (scene bootstrap), and for each
oracle row either run holds, both ``row``s' share of the oracle's lead over the reference (``metrics.share_of_gap``)
on the oracle's scenes.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from jaxcls import metrics, report
from jaxcls.config import load_config
from jaxcls.episode import protocol
from jaxcls.experiments.table1 import data
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.world.objects import object_set_from_config


def _episodes(records: list[dict], classifier: str, row: str) -> dict[tuple, dict]:
    return {data.record_key(r): r for r in records if r["classifier"] == classifier and r["row"] == row}


def check_same_scenes(a: list[dict], b: list[dict], classifier: str, reference: str) -> int:
    """The number of ``reference`` episodes of ``classifier`` both record lists hold, each with the same path and
    refined labels; ValueError naming the first that differs, or where none is shared."""
    ea, eb = _episodes(a, classifier, reference), _episodes(b, classifier, reference)
    shared = sorted(ea.keys() & eb.keys())
    if not shared:
        raise ValueError(f"classifier {classifier!r}: the runs share no {reference} episode to check that they "
                         "drew the same scenes, starts and keys (choose another --reference)")
    for k in shared:
        for field in ("start", "path", "true", "refined"):
            if ea[k][field] != eb[k][field]:
                raise ValueError(f"classifier {classifier!r}: {reference} episode (scene {k[2]}, run {k[3]}) has "
                                 f"another {field} in the two runs: they did not draw the same scenes, starts and "
                                 "keys, or ran that row with other settings")
    return len(shared)


def _labels(records: list[dict], classifier: str, row: str, scenes: set[int], moves: int) -> list:
    return protocol.per_scene([r for r in records if r["classifier"] == classifier and r["row"] == row
                               and r["scene"] in scenes], moves)


def _scenes(records: list[dict], classifier: str, row: str) -> set[int]:
    return {int(r["scene"]) for r in records if r["classifier"] == classifier and r["row"] == row}


def tables(a: list[dict], b: list[dict], classifiers: list[str], row: str, reference: str, classes: int,
           moves: int, resamples: int = 2000) -> str:
    """Markdown: per classifier, the reference check, B's ``row`` - A's on their common scenes after ``moves``, and
    the shares of each oracle row's lead over ``reference`` that both close."""
    label, ref_label = protocol.ROWS[row].label, protocol.ROWS[reference].label
    lines = []
    for c in classifiers:
        checked = check_same_scenes(a, b, c, reference)
        common = _scenes(a, c, row) & _scenes(b, c, row) & _scenes(a, c, reference)
        if not common:
            raise ValueError(f"classifier {c!r}: the runs have no scene of {row} in common")
        diff = metrics.paired_difference(_labels(b, c, row, common, moves), _labels(a, c, row, common, moves), classes,
                                         resamples=resamples)
        lines += [f"#### Classifier `{c}`", "",
                  f"- {ref_label}: the same path and labels in all {checked} episodes both runs hold.",
                  f"- {label}: B - A on {len(common)} scenes: {metrics.format_difference(*diff)}", ""]
        oracles = [(name, run) for run in (a, b) for name in sorted({r["row"] for r in run if r["classifier"] == c})
                   if protocol.ROWS[name].kind is protocol.Kind.ORACLE]
        if oracles:
            lines += [f"| oracle row (its scenes) | oracle - {ref_label} | share A | share B | B - A there |",
                      "| --- | --- | --- | --- | --- |"]
        for name, run in oracles:
            there = common & _scenes(run, c, name)
            oracle, base = _labels(run, c, name, there, moves), _labels(a, c, reference, there, moves)
            pa, pb = _labels(a, c, row, there, moves), _labels(b, c, row, there, moves)
            lead = metrics.paired_difference(oracle, base, classes, resamples=resamples)
            shares = [metrics.share_of_gap(p, base, oracle, classes, resamples=resamples) for p in (pa, pb)]
            there_diff = metrics.paired_difference(pb, pa, classes, resamples=resamples)
            lines.append(f"| {protocol.ROWS[name].label} ({len(there)}) | {metrics.format_difference(*lead)} | "
                         + " | ".join(metrics.format_difference(*s) for s in shares)
                         + f" | {metrics.format_difference(*there_diff)} |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--a", required=True, help="a Table 1 run's config.yaml (A)")
    parser.add_argument("--b", required=True, help="another run's config.yaml on the same scenes (B)")
    parser.add_argument("--row", default="learned_gr", choices=sorted(protocol.ROWS), help="the row compared")
    parser.add_argument("--reference", default="info_gain_gr", choices=sorted(protocol.ROWS),
                        help="a row both ran alike: the check that the scenes agree, and the base of the share")
    parser.add_argument("--out", help="append the tables to this Markdown file")
    args = parser.parse_args(argv)
    configs = [load_config(Table1Config, path) for path in (args.a, args.b)]
    runs = []
    for path, config in zip((args.a, args.b), configs, strict=True):
        records = data.stored_records(config, Path(config.out_dir) / "episodes.jsonl")
        if not records:
            parser.error(f"{path}: no stored episodes of this config in {config.out_dir}")
        runs.append(records)
    if configs[0].moves != configs[1].moves:
        parser.error(f"{args.a} runs {configs[0].moves} moves, {args.b} {configs[1].moves}")
    datasets = [data.dataset_config(c).objects for c in configs]
    if datasets[0] != datasets[1]:
        parser.error(f"{args.a} and {args.b} score other object sets")
    classifiers = [c for c in configs[0].classifiers if c in configs[1].classifiers]
    if not classifiers:
        parser.error(f"{args.a} and {args.b} share no classifier")
    classes = len(object_set_from_config(datasets[0]).classes)
    try:
        report.publish(tables(*runs, classifiers, args.row, args.reference, classes,
                              configs[0].moves, configs[0].resamples), args.out)
    except ValueError as e:
        parser.error(str(e))


if __name__ == "__main__":
    main()
