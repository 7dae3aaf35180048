"""Two Table 1 runs of the same scenes and seeds (folders of episodes*.jsonl): how many records agree, and per row
the pooled F1 at move T of each with the paired scene-bootstrap difference (b - a), per classifier and row.

    python results/tracking_levels_2026-11-27/compare.py RUN_A RUN_B CLASSES [MOVES]
"""

import json
import sys
from pathlib import Path

import numpy as np

from jaxcls import metrics
from jaxcls.episode import protocol


def load(folder: str) -> list[dict]:
    return [json.loads(line) for f in sorted(Path(folder).glob("episodes*.jsonl")) for line in open(f)]


def key(record: dict) -> tuple:
    return record["classifier"], record["row"], record["scene"], record["run"]


def pooled_f1(labels: list, classes: int) -> float:
    truth, predicted = (np.concatenate(x) for x in zip(*labels, strict=True))
    return metrics.classification_scores(truth, predicted, classes).f1


def main() -> None:
    A, B = load(sys.argv[1]), load(sys.argv[2])
    classes, moves = int(sys.argv[3]), int(sys.argv[4]) if len(sys.argv) > 4 else 10
    a, b = {key(r): r for r in A}, {key(r): r for r in B}
    same = sum(a[k]["path"] == b[k]["path"] and a[k]["refined"] == b[k]["refined"] for k in a if k in b)
    print(f"records {len(a)} / {len(b)}; same path and refined labels: {same}")
    several = len({k[0] for k in a}) > 1  # (classifiers named where a run has several)
    for c, row in sorted({k[:2] for k in a}):
        la = protocol.scene_labels([r for r in A if key(r)[:2] == (c, row)]).at(moves)
        lb = protocol.scene_labels([r for r in B if key(r)[:2] == (c, row)]).at(moves)
        (estimate, low, high), = metrics.paired_differences([(lb, la)], classes, resamples=2000)
        print(f"{f'{c} ' if several else ''}{row}: F1 {pooled_f1(la, classes):.3f} -> {pooled_f1(lb, classes):.3f}; "
              f"paired (b - a) {estimate:+.3f} [{low:+.3f}, {high:+.3f}]")


if __name__ == "__main__":
    main()
