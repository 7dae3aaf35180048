"""Table 1's records on the host: ``protocol.episode_records`` (a scene's episodes matched to its objects
together, every move at once, the unique optima taken directly and the rest through SciPy) against matching each
move of each episode on its own (``scoring.object_labels``, SciPy's Hungarian a move: what it replaced),
interleaved, on a synthetic call shaped as Table 1's (100 scenes x 10 runs x 10 moves, 5 objects, 8 segment
slots, segments near the objects the view shows, a few spurious or dead).

    python benchmarks/records.py [--scenes 100 --runs 10 --moves 10 --repeats 5 --out BENCHMARKS.md]

The two must give the same labels; the table says which share of the moves took the direct path.

``--tables``: the tables of a whole run instead: every row's labels per scene prepared once for all moves
(``protocol.scene_labels``, what ``tables.tables`` does) against pooling them again for each move
(``protocol.per_scene`` a move: what it replaced), interleaved, on synthetic records shaped as a 1,000-scene run
(10 rows x 1,000 scenes x 10 runs, 10 moves; this script's calls matched by ``protocol.episode_records``); then
the whole ``tables.tables`` (scores, intervals, paired differences). The two must give the same labels.

    python benchmarks/records.py --tables [--scenes 1000 --repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
from types import SimpleNamespace

import numpy as np

from jaxcls import metrics, report
from jaxcls.episode import protocol, scoring
from jaxcls.experiments.table1 import runner, tables
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.perception import tracking


def synthetic_call(scenes: int, runs: int, moves: int, objects: int = 5, slots: int = 8, seed: int = 0):
    """(traces with [E, T, ...] leaves, a truth per episode) for E = scenes x runs episodes: each move's segments
    lie within ~5 mm of 2 to ``objects`` of its scene's objects, one in ten moves adds a spurious one, about one
    slot in ten is dead; some episodes stop early."""
    rng = np.random.default_rng(seed)
    E = scenes * runs
    truths = [SimpleNamespace(centroid=rng.uniform(-0.25, 0.25, (objects, 3)), label=rng.integers(0, 8, objects),
                              target=np.arange(3)) for _ in range(scenes)]
    centroid = rng.uniform(-0.3, 0.3, (E, moves, slots, 3))
    valid = np.zeros((E, moves, slots), bool)
    for e in range(E):
        truth = truths[e // runs]
        for t in range(moves):
            seen = rng.permutation(objects)[:rng.integers(2, objects + 1)]
            count = len(seen) + (rng.random() < 0.1)
            centroid[e, t, :len(seen)] = truth.centroid[seen] + rng.normal(0, 0.005, (len(seen), 3))
            valid[e, t, :count] = rng.random(count) > 0.1
    refinement = SimpleNamespace(prior=rng.integers(0, 8, (E, moves, slots)),
                                 refined=rng.integers(0, 8, (E, moves, slots)), valid=valid)
    done = np.cumsum(rng.random((E, moves)) < 0.02, axis=1) > 0
    traces = SimpleNamespace(refinement=refinement, centroid=centroid, done=done,
                             view=rng.integers(0, 100, (E, moves)), tracking=np.zeros((E, moves), np.int32),
                             hand_eye=np.tile(np.eye(4, dtype=np.float32), (E, moves, 1, 1)))
    return traces, [truths[e // runs] for e in range(E)]


def records_one_at_a_time(traces, truths, keys) -> list[dict]:
    """``episode_records`` as it was: the same hand-eye logs, every move of every episode matched on its own
    (``scoring.object_labels``, SciPy a move)."""
    r, done = traces.refinement, traces.done
    hand_eye = np.round(np.asarray(protocol._se3_log(np.asarray(traces.hand_eye, np.float32)), np.float64), 6)
    names = {s.value: s.name.lower() for s in tracking.Status}
    records = []
    for e, (truth, key) in enumerate(zip(truths, keys, strict=True)):
        labels, phantoms, segments = [], [], []
        for t in range(done.shape[1]):
            if done[e, t] and labels:
                labels.append(labels[-1]), phantoms.append(phantoms[-1]), segments.append(segments[-1])
                continue
            both = np.stack([r.prior[e, t], r.refined[e, t]])
            labels.append(scoring.object_labels(truth, traces.centroid[e, t], r.valid[e, t], both)[:, truth.target])
            match = metrics.match_objects(traces.centroid[e, t], r.valid[e, t], truth.centroid)
            live = np.asarray(r.valid[e, t], bool)
            phantoms.append([int(r.refined[e, t, n]) for n in np.flatnonzero(live) if n not in set(match.tolist())])
            segments.append(int(live.sum()))
        made, labels = ~done[e], np.stack(labels)
        records.append({**key, "path": traces.view[e][made].tolist(), "true": truth.label[truth.target].tolist(),
                        "prior": labels[:, 0].tolist(), "refined": labels[:, 1].tolist(),
                        "tracking": [names[s] for s in traces.tracking[e][made]],
                        "hand_eye": hand_eye[e][made].tolist(), "phantom": phantoms, "segments": segments,
                        "objects": len(truth.label)})
    return records


def direct_share(traces, truths) -> float:
    """The share of moves whose matching took the direct path (a unique optimum; not SciPy)."""
    slow = []
    original = metrics._hungarian  # what the direct path falls back to
    metrics._hungarian = lambda *a, **k: slow.append(1) or original(*a, **k)
    try:
        protocol.episode_records(traces, truths, [{} for _ in truths])
    finally:
        metrics._hungarian = original
    return 1 - len(slow) / traces.done.size


ROWS = tuple(n for n in protocol.PAPER_ROWS if protocol.ROWS[n].kind in runner.BATCHED)  # Table 1's batched rows


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


def tables_benchmark(args: argparse.Namespace, argv: list[str] | None) -> None:
    """``--tables``: the labels per scene of a run's rows, prepared once against a move at a time; the whole tables."""
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
    times, results = report.interleaved(contenders, args.repeats)
    ours, theirs = results.values()
    same = all(np.array_equal(a, c) and np.array_equal(b, d)
               for x, y in zip(ours, theirs, strict=True) for (a, b), (c, d) in zip(x, y, strict=True))
    # Every row's F1 interval after every move, and the paired differences against VisOcclHistGR: in one bootstrap a
    # row (and one for the differences), against a bootstrap each (what it replaced). The same seed: the same bounds.
    labels = {row: protocol.scene_labels(recs) for row, recs in by.items()}
    base_row = "vis_occl_hist_gr"

    def one_bootstrap_a_row():
        pairs = [(labels[r].at(args.moves), labels[base_row].at(args.moves)) for r in labels if r != base_row]
        return [*(metrics.scene_intervals([lab.at(t) for t in moves], 8) for lab in labels.values()),
                metrics.paired_differences(pairs, 8)]

    def a_bootstrap_each():
        pairs = [(labels[r].at(args.moves), labels[base_row].at(args.moves)) for r in labels if r != base_row]
        return [*([metrics.scene_interval(lab.at(t), 8) for t in moves] for lab in labels.values()),
                [metrics.paired_difference(a, b, 8) for a, b in pairs]]

    bootstraps = {"metrics.scene_intervals / paired_differences: a row's moves (the differences) in one bootstrap":
                  one_bootstrap_a_row,
                  "metrics.scene_interval / paired_difference: a bootstrap a move and a difference": a_bootstrap_each}
    b_times, b_results = report.interleaved(bootstraps, args.repeats)
    ours_b, theirs_b = b_results.values()
    same_b = all(np.allclose(x, y, rtol=0, atol=1e-12) for x, y in zip(ours_b, theirs_b, strict=True))
    config = Table1Config(rows=list(ROWS), classifiers={"c": ""}, moves=args.moves, runs=args.runs)
    whole = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        tables.tables(config, records, 8, None, [])
        whole.append(time.perf_counter() - t0)
    base = statistics.median(times[next(iter(times))])
    rows = [(name, report.device_name(), len(records), f"{statistics.median(t):.2f}", f"{min(t):.2f}-{max(t):.2f}",
             f"{statistics.median(t) / base:.1f}", "yes" if same else "NO") for name, t in times.items()]
    b_base = statistics.median(b_times[next(iter(b_times))])
    rows += [(name, report.device_name(), len(records), f"{statistics.median(t):.2f}", f"{min(t):.2f}-{max(t):.2f}",
              f"{statistics.median(t) / b_base:.1f}", "yes" if same_b else "NO") for name, t in b_times.items()]
    rows.append(("the whole tables.tables (scores, intervals, paired differences)", report.device_name(),
                 len(records), f"{statistics.median(whole):.2f}", f"{min(whole):.2f}-{max(whole):.2f}", "-", "-"))
    report.publish(report.section(
        "Table 1's tables of a 1,000-scene run on the host", argv,
        ("step", "device", "records", "median s", "range s", "its time / ours", "same result as ours"),
        rows, intro=f"{len(ROWS)} rows x {args.scenes} scenes x {args.runs} runs, labels after each of "
                    f"{args.moves} moves, {args.repeats} interleaved rounds; synthetic records."), args.out)
    if not (same and same_b):
        raise SystemExit("the two poolings or the two bootstraps differ")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tables", action="store_true", help="time the tables of a whole run instead (above)")
    parser.add_argument("--scenes", type=int, help="scenes (default 100; 1,000 with --tables)")
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--moves", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    if args.tables:
        args.scenes = 1000 if args.scenes is None else args.scenes
        return tables_benchmark(args, argv)
    args.scenes = 100 if args.scenes is None else args.scenes
    traces, truths = synthetic_call(args.scenes, args.runs, args.moves)
    keys = [{"scene": e // args.runs, "run": e % args.runs} for e in range(len(truths))]
    contenders = {"protocol.episode_records (a scene's moves at once)":
                  lambda: protocol.episode_records(traces, truths, keys),
                  "every move matched on its own (SciPy a move)": lambda: records_one_at_a_time(traces, truths, keys)}
    contenders[next(iter(contenders))]()  # the hand-eye logs' program compiles
    times, results = report.interleaved(contenders, args.repeats)
    same = len({repr(r) for r in results.values()}) == 1
    share = direct_share(traces, truths)
    E = len(truths)
    base = float(np.median(times[list(contenders)[1]]))
    rows = [(name, report.cpu_name(), f"{np.median(t):.3f}", f"{min(t):.3f}-{max(t):.3f}",
             f"{np.median(t) / E * 1e3:.3f}", f"{base / np.median(t):.1f}x", "yes" if same else "NO")
            for name, t in times.items()]
    for row in rows:
        print(row, flush=True)
    report.publish(report.section(
        f"Table 1's records of one call on the host ({E} episodes x {args.moves} moves)", argv,
        ("method", "machine", "median s", "range s", "ms an episode", "speed-up", "same records"), rows,
        intro=f"A synthetic call shaped as Table 1's ({args.scenes} scenes x {args.runs} runs, 5 objects, 8 segment "
              f"slots); {args.repeats} interleaved rounds. {share:.0%} of the moves were matched directly (a unique "
              "optimum), the rest through SciPy's Hungarian assignment."), args.out)


if __name__ == "__main__":
    main()
