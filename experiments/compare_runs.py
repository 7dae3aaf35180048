"""One row of two Table 1 runs on the same scenes, paired episode by episode: an A/B of two settings that one run
cannot hold both of (two policy weights in ``learned_gr``, say), with each run's oracle rows for the share of the
gap.

    python experiments/compare_runs.py \\
        --a results/learned_policy_2026-11-29/rollout_labels/table1_real_like_paper_fair/config.yaml \\
        --b results/learned_policy_2026-11-29/rollout_labels/table1_real_like_paper_ppo/config.yaml \\
        [--row learned_gr] [--reference info_gain_gr] [--out FILE]

``--a`` / ``--b`` are Table 1 runs' configs (their ``out_dir`` holds the stored episodes, ``episodes.jsonl`` or its
``.xz`` archive). The (scene, run) episodes both runs stored are paired (``data.paired_runs``). The runs must have
drawn the same scenes, starts and keys: the ``--reference`` row, which both ran with the same settings, must have
the same start, path and labels in every episode both hold, else the runs are refused. Then, per classifier:
``row`` of B - ``row`` of A on their paired episodes (scene bootstrap), and for each oracle row of either run both
``row``s' share of the oracle's lead over the reference (``metrics.share_of_gap``) on the oracle's episodes, and
the same share with each ``row``'s lead over the reference taken on all the paired episodes
(``metrics.share_of_gap_all_scenes``: the oracle runs on a subset, whose draw of the lead it carries otherwise).
The settings in which the two configs differ are listed first.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from jaxcls import metrics, report
from jaxcls.config import load_config
from jaxcls.episode import protocol
from jaxcls.experiments.table1 import data
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.experiments.table1.scoring import format_share
from jaxcls.world.objects import object_set_from_config

Records = list[dict[str, Any]]


def check_same_scenes(pairs: dict[tuple[str, str], tuple[Records, Records]], classifier: str, reference: str) -> int:
    """The number of ``reference`` episodes of ``classifier`` two runs both hold (``pairs``: ``data.paired_runs``
    of them), each with the same start, path, true and refined labels; ValueError naming the first that differs,
    or where none is shared."""
    pair = pairs.get((classifier, reference))
    if not pair:
        raise ValueError(f"classifier {classifier!r}: the runs share no {reference} episode to check that they "
                         "drew the same scenes, starts and keys (choose another --reference)")
    for x, y in zip(*pair, strict=True):
        for field in ("start", "path", "true", "refined"):
            if x[field] != y[field]:
                raise ValueError(f"classifier {classifier!r}: {reference} episode (scene {x['scene']}, run "
                                 f"{x['run']}) has another {field} in the two runs: they did not draw the same "
                                 "scenes, starts and keys, or ran that row with other settings")
    return len(pair[0])


def _keys(records: Records) -> set[tuple]:
    return {data.record_key(r)[2:] for r in records}


def _on(records: Records, keys: set[tuple], moves: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(true [n_s], predicted [n_s])] per scene after ``moves`` of the episodes (scene, run) in ``keys``."""
    return protocol.per_scene([r for r in records if data.record_key(r)[2:] in keys], moves)


def _share(interval: tuple[float, float, float]) -> str:
    return "{} [{}, {}]".format(*map(format_share, interval))


def tables(a: Records, b: Records, classifiers: list[str], row: str, reference: str, classes: int, moves: int,
           resamples: int = 2000) -> str:
    """Markdown: per classifier, the reference check, B's ``row`` - A's on their paired episodes after ``moves``,
    and each oracle row's (of run A or B) lead over ``reference`` with the shares of it both close, on the
    episodes all of them hold (at least 2 scenes; fewer: said, no interval)."""
    label, ref_label = protocol.ROWS[row].label, protocol.ROWS[reference].label
    lines, pairs = [], data.paired_runs(a, b)
    for c in classifiers:
        checked = check_same_scenes(pairs, c, reference)
        if (c, row) not in pairs:
            raise ValueError(f"classifier {c!r}: the runs have no episode of {row} in common")
        (row_a, row_b), (ref_a, _) = pairs[c, row], pairs[c, reference]
        common = _keys(row_a) & _keys(ref_a)
        all_a, all_b, all_ref = (_on(x, common, moves) for x in (row_a, row_b, ref_a))
        diff = metrics.paired_difference(all_b, all_a, classes, resamples=resamples)
        scenes = len({k[0] for k in common})
        lines += [f"#### Classifier `{c}`", "",
                  f"- {ref_label}: the same start, path and labels in all {checked} episodes both runs hold.",
                  f"- {label}: B - A on {len(common)} episodes of {scenes} scenes: {metrics.format_difference(*diff)}",
                  ""]
        oracles = [(run_name, name, [r for r in run if r["classifier"] == c and r["row"] == name])
                   for run_name, run in (("A", a), ("B", b))
                   for name in sorted({r["row"] for r in run if r["classifier"] == c})
                   if protocol.ROWS[name].kind is protocol.Kind.ORACLE]
        if oracles:
            lines += [f"| oracle row (run: episodes, scenes) | oracle - {ref_label} | share A closes | share B closes "
                      f"| B - A there | share A closes, its lead on all {scenes} scenes | share B closes, likewise |",
                      "| --- | --- | --- | --- | --- | --- | --- |"]
        for run_name, name, episodes in oracles:
            there = common & _keys(episodes)
            head = f"| {protocol.ROWS[name].label} ({run_name}: {len(there)}, {len({k[0] for k in there})}) |"
            if len({k[0] for k in there}) < 2:
                lines.append(head + " fewer than 2 scenes in common: no interval | | | | | |")
                continue
            oracle, base = _on(episodes, there, moves), _on(ref_a, there, moves)
            pa, pb = _on(row_a, there, moves), _on(row_b, there, moves)
            lead = metrics.paired_difference(oracle, base, classes, resamples=resamples)
            shares = [metrics.share_of_gap(p, base, oracle, classes, resamples=resamples) for p in (pa, pb)]
            there_diff = metrics.paired_difference(pb, pa, classes, resamples=resamples)
            inside = np.isin(sorted({k[0] for k in common}), sorted({k[0] for k in there}))  # (per_scene's order)
            everywhere = [metrics.share_of_gap_all_scenes(p, all_ref, oracle, base, inside, classes,
                                                          resamples=resamples) for p in (all_a, all_b)]
            lines.append(f"{head} {metrics.format_difference(*lead)} | {_share(shares[0])} | {_share(shares[1])} | "
                         f"{metrics.format_difference(*there_diff)} | {_share(everywhere[0])} | "
                         f"{_share(everywhere[1])} |")
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
    if configs[0].moves != configs[1].moves:
        parser.error(f"{args.a} runs {configs[0].moves} moves, {args.b} {configs[1].moves}")
    objects = [data.dataset_config(c).objects for c in configs]
    if objects[0] != objects[1]:
        parser.error(f"{args.a} and {args.b} score other object sets")
    classifiers = [c for c in configs[0].classifiers if c in configs[1].classifiers]
    if not classifiers:
        parser.error(f"{args.a} and {args.b} share no classifier")
    runs = []
    for path, config in zip((args.a, args.b), configs, strict=True):
        records = data.stored_records(config, Path(config.out_dir) / "episodes.jsonl")
        if not records:
            parser.error(f"{path}: no stored episodes of this config in {config.out_dir}")
        runs.append(records)
    classes = len(object_set_from_config(objects[0]).classes)
    differ = [k for k in data.settings_differ(*configs) if k != "out_dir"]
    head = (f"A: `{args.a}`; B: `{args.b}`; their settings differ in: {', '.join(differ) or 'nothing'}.\n\n")
    try:
        report.publish(head + tables(*runs, classifiers, args.row, args.reference, classes, configs[0].moves,
                                     configs[0].resamples), args.out)
    except ValueError as e:
        parser.error(str(e))


if __name__ == "__main__":
    main()
