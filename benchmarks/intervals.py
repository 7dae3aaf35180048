"""Table 1's scene-bootstrap intervals on 1,000 scenes: ``metrics.scene_interval`` (each resample's sum of the
scenes' confusion matrices as scene counts times the matrices) against the same bootstrap summing a gather of
the matrices (``cms[picks].sum(axis=-3)``, what it replaced), interleaved on the rows of a stored run.

    python benchmarks/intervals.py --labels results/table1_real_like_1000_paper/labels.jsonl.xz [--out ...]

``labels.jsonl.xz``: per episode the labels after move 5 and after move T (a ``results/table1_*`` folder);
each row's F1 interval after move T, 2,000 resamples; the two must give the same interval.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from jaxcls import io, metrics, report


def per_scene_rows(path: str) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """{row: [(true [n_s], refined after T [n_s])] per scene} of a stored run's labels."""
    scenes: dict[str, dict[int, list]] = {}
    for r in io.read_jsonl(path):
        scenes.setdefault(r["row"], {}).setdefault(r["scene"], []).append((r["true"], r["refined"][-1]))
    return {row: [(np.concatenate([np.asarray(t) for t, _ in runs]), np.concatenate([np.asarray(p) for _, p in runs]))
                  for _, runs in sorted(by.items())] for row, by in scenes.items()}


def gathered_interval(per_scene, classes: int, resamples: int) -> tuple[float, float, float]:
    """The bootstrap of ``scene_interval`` with each resample's sum taken over a gather of the matrices."""
    cms = metrics._scene_confusions(per_scene, classes)
    return metrics._interval(lambda picks: metrics.confusion_scores(cms[picks].sum(axis=-3))["f1"], len(cms), 0.95,
                             resamples, 0)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--labels", default="results/table1_real_like_1000_paper/labels.jsonl.xz")
    parser.add_argument("--classes", type=int, default=10)
    parser.add_argument("--resamples", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    rows = per_scene_rows(args.labels)
    contenders = {"metrics.scene_interval (scene counts x matrices)":
                  lambda s: metrics.scene_interval(s, args.classes, resamples=args.resamples),
                  "the same bootstrap over a gather of the matrices":
                  lambda s: gathered_interval(s, args.classes, args.resamples)}
    times = {name: [] for name in contenders}
    results = {}
    for _ in range(args.repeats):
        for name, interval in contenders.items():
            t0 = time.perf_counter()
            results[name] = [interval(per_scene) for per_scene in rows.values()]
            times[name].append(time.perf_counter() - t0)
    base = next(iter(contenders))
    table = [(name, report.cpu_name(), len(rows), len(next(iter(rows.values()))), f"{np.median(t):.2f}",
              f"{min(t):.2f}-{max(t):.2f}", f"{np.median(t) / np.median(times[base]):.1f}",
              "yes" if results[name] == results[base] else "no") for name, t in times.items()]
    report.publish(report.section(
        "Table 1's scene-bootstrap intervals", argv,
        ("bootstrap", "device", "rows", "scenes", "median s (all rows)", "range s", "its time / ours",
         "same intervals as ours"), table,
        intro=f"Each row's F1 interval after move T, {args.resamples} resamples, {args.repeats} interleaved rounds; "
              f"{args.labels}."), args.out)


if __name__ == "__main__":
    main()
