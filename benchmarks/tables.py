"""Table 1's tables of a whole run on the host: every row's labels per scene prepared once for all moves
(``protocol.scene_labels``, what ``tables.tables`` does) against pooling them again for each move
(``protocol.per_scene`` a move: what it replaced), interleaved, on synthetic records shaped as a 1,000-scene
run (10 rows x 1,000 scenes x 10 runs, 10 moves, 3 targets; ``records.synthetic_call``'s segments matched by
``protocol.episode_records``); then the whole ``tables.tables`` (scores, intervals, paired differences).

    python benchmarks/tables.py [--scenes 1000 --runs 10 --repeats 3 --out BENCHMARKS.md]

The two must give the same labels per scene after every move.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from records import synthetic_call

from jaxcls import report
from jaxcls.episode import protocol
from jaxcls.experiments.table1 import tables
from jaxcls.experiments.table1.config import Table1Config

ROWS = ("single", "single_gr", "random", "random_gr", "vis_no_occl", "vis_no_occl_gr", "vis_occl", "vis_occl_gr",
        "vis_occl_hist", "vis_occl_hist_gr")


def run_records(scenes: int, runs: int, moves: int) -> list[dict]:
    """Every row's records of ``scenes`` x ``runs`` episodes (the same synthetic traces for each row, 100 scenes
    a call, as Table 1's calls)."""
    out = []
    for first in range(0, scenes, 100):
        count = min(100, scenes - first)
        traces, truths = synthetic_call(count, runs, moves, seed=first)
        for row in ROWS:
            keys = [{"classifier": "c", "row": row, "scene": first + e // runs, "run": e % runs, "start": 0}
                    for e in range(count * runs)]
            out += protocol.episode_records(traces, truths, keys)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=1000)
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--moves", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args()
    records = run_records(args.scenes, args.runs, args.moves)
    by: dict[str, list[dict]] = {}
    for r in records:
        by.setdefault(r["row"], []).append(r)
    moves = range(1, args.moves + 1)

    def prepared_once():
        prepared = [protocol.scene_labels(recs) for recs in by.values()]  # once a row
        return [labels.at(t) for labels in prepared for t in moves]

    def a_move_at_a_time():
        return [protocol.per_scene(recs, t) for recs in by.values() for t in moves]

    contenders = {"protocol.scene_labels, once a row for every move": prepared_once,
                  "protocol.per_scene, a row's records pooled again each move": a_move_at_a_time}
    times = {name: [] for name in contenders}
    results = {}
    for _ in range(args.repeats):
        for name, fn in contenders.items():
            t0 = time.perf_counter()
            results[name] = fn()
            times[name].append(time.perf_counter() - t0)
    ours, theirs = results.values()
    same = all(np.array_equal(a, c) and np.array_equal(b, d)
               for x, y in zip(ours, theirs, strict=True) for (a, b), (c, d) in zip(x, y, strict=True))
    config = Table1Config(rows=list(ROWS), classifiers={"c": ""}, moves=args.moves, runs=args.runs)
    whole = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        tables.tables(config, records, 8, None, [])
        whole.append(time.perf_counter() - t0)
    base = statistics.median(times[next(iter(times))])
    rows = [(name, report.device_name(), len(records), f"{statistics.median(t):.2f}", f"{min(t):.2f}-{max(t):.2f}",
             f"{statistics.median(t) / base:.1f}", "yes" if same else "NO") for name, t in times.items()]
    rows.append(("the whole tables.tables (scores, intervals, paired differences)", report.device_name(),
                 len(records), f"{statistics.median(whole):.2f}", f"{min(whole):.2f}-{max(whole):.2f}", "-", "-"))
    report.publish(report.section(
        "Table 1's tables of a 1,000-scene run on the host", None,
        ("labels per scene", "device", "records", "median s", "range s", "its time / ours", "same labels as ours"),
        rows, intro=f"{len(ROWS)} rows x {args.scenes} scenes x {args.runs} runs, labels after each of "
                    f"{args.moves} moves, {args.repeats} interleaved rounds; synthetic records."), args.out)
    if not same:
        raise SystemExit("the two poolings differ")


if __name__ == "__main__":
    main()
