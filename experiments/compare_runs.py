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

Several pairs (``--a A1 --b B1 --a A2 --b B2 ...``), each pair on its own draw of scenes (another dataset seed),
are pooled: each pair is checked as above, then pair i's scenes are numbered after pair i - 1's (``pool``) and the
tables are those of one run on all the scenes, every draw's scenes resampled as one set (the draws are
independent scenes of one distribution): the oracle's scenes of every draw pin its lead, and every draw's scenes
the policies'. Pairs of one dataset seed are refused: they hold the same scenes (another Table 1 seed changes only
the starts), which would count twice. The A runs should run the same policy in ``row``, and the B runs likewise:
where their settings differ, the keys are listed, for the reader to judge (a policy file and its shipped name,
say). An oracle row pools over the pairs that hold it in the same run, A or B.
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
    """Markdown: per classifier, the reference check, B's ``row`` - A's on their paired episodes after ``moves``
    and each one's lead over ``reference`` there, and each oracle row's (of run A or B) lead over ``reference``
    with the shares of it both close, on the episodes all of them hold (at least 2 scenes; fewer: said, no
    interval)."""
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
        leads = [metrics.paired_difference(x, all_ref, classes, resamples=resamples) for x in (all_a, all_b)]
        scenes = len({k[0] for k in common})
        lines += [f"#### Classifier `{c}`", "",
                  f"- {ref_label}: the same start, path and labels in all {checked} episodes both runs hold.",
                  f"- {label}: B - A on {len(common)} episodes of {scenes} scenes: {metrics.format_difference(*diff)}",
                  f"- {label} - {ref_label} there: A {metrics.format_difference(*leads[0])}, "
                  f"B {metrics.format_difference(*leads[1])}", ""]
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


def pool(pairs: list[tuple[Records, Records]]) -> tuple[Records, Records]:
    """One run A and one run B from pairs of runs on different draws of scenes: pair i's scene indices shifted past
    every earlier pair's (the records are copied, not changed), so that no two draws share a scene."""
    a, b, offset = [], [], 0
    for x, y in pairs:
        a += [dict(r, scene=int(r["scene"]) + offset) for r in x]
        b += [dict(r, scene=int(r["scene"]) + offset) for r in y]
        offset += 1 + max((int(r["scene"]) for r in x + y), default=-1)
    return a, b


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--a", required=True, action="append",
                        help="a Table 1 run's config.yaml (A); again for each further pair, pooled")
    parser.add_argument("--b", required=True, action="append",
                        help="another run's config.yaml on the same scenes as its --a (B)")
    parser.add_argument("--row", default="learned_gr", choices=sorted(protocol.ROWS), help="the row compared")
    parser.add_argument("--reference", default="info_gain_gr", choices=sorted(protocol.ROWS),
                        help="a row both ran alike: the check that the scenes agree, and the base of the share")
    parser.add_argument("--out", help="append the tables to this Markdown file")
    args = parser.parse_args(argv)
    if len(args.a) != len(args.b):
        parser.error(f"{len(args.a)} --a and {len(args.b)} --b: give them in pairs")
    paths = list(zip(args.a, args.b, strict=True))
    configs = [(load_config(Table1Config, pa), load_config(Table1Config, pb)) for pa, pb in paths]
    flat = [(path, config) for pair in zip(paths, configs, strict=True) for path, config in zip(*pair, strict=True)]
    datasets = [data.dataset_config(config) for _, config in flat]
    for (path, config), dataset in zip(flat[1:], datasets[1:], strict=True):
        if config.moves != flat[0][1].moves:
            parser.error(f"{flat[0][0]} runs {flat[0][1].moves} moves, {path} {config.moves}")
        if dataset.objects != datasets[0].objects:
            parser.error(f"{flat[0][0]} and {path} score other object sets")
    draws = [d.seed for d in datasets[::2]]  # (a pair's scenes: its dataset's seed; a Table 1 seed draws the starts)
    for i, (pair, draw) in enumerate(zip(paths, draws, strict=True)):
        if draw in draws[:i]:
            parser.error(f"{pair[0]} draws the same scenes as {paths[draws.index(draw)][0]} (dataset seed {draw}): "
                         "pooled, they would count twice")
    classifiers = [c for c in flat[0][1].classifiers if all(c in config.classifiers for _, config in flat)]
    if not classifiers:
        parser.error(f"{', '.join(p for p, _ in flat)} share no classifier")
    runs = []
    for path, config in flat:
        records = data.stored_records(config, Path(config.out_dir) / "episodes.jsonl")
        if not records:
            parser.error(f"{path}: no stored episodes of this config in {config.out_dir}")
        runs.append(records)
    pairs = list(zip(runs[::2], runs[1::2], strict=True))
    classes = len(object_set_from_config(datasets[0].objects).classes)
    head = []
    for (pa, pb), (ca, cb) in zip(paths, configs, strict=True):
        differ = [k for k in data.settings_differ(ca, cb) if k != "out_dir"]
        head.append(f"A: `{pa}`; B: `{pb}`; their settings differ in: {', '.join(differ) or 'nothing'}.")
    if len(pairs) > 1:
        for name, i in (("A", 0), ("B", 1)):
            differ = sorted({k for c in configs[1:] for k in data.settings_differ(configs[0][i], c[i])
                             if k != "out_dir"})
            head.append(f"The {name} runs differ in: {', '.join(differ) or 'nothing'}.")
        head.append(f"Pooled: {len(pairs)} pairs, each its own draw of scenes (dataset seeds "
                    f"{', '.join(map(str, draws))}), their scenes resampled as one set.")
    try:
        for i, (a, b) in enumerate(pairs):  # (each pair checked on its own scenes, its errors named by them)
            paired = data.paired_runs(a, b)
            for c in classifiers:
                try:
                    check_same_scenes(paired, c, args.reference)
                except ValueError as e:
                    raise ValueError(f"{paths[i][0]} and {paths[i][1]}: {e}") from None
        report.publish("\n\n".join(head) + "\n\n" + tables(*pool(pairs), classifiers, args.row, args.reference,
                                                            classes, flat[0][1].moves, flat[0][1].resamples),
                       args.out)
    except ValueError as e:
        parser.error(str(e))


if __name__ == "__main__":
    main()
