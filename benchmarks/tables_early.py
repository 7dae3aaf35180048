"""Table 1's tables of a stored run made all at the end, against made after its rows were tabulated early
(``tables.EarlyRows``: ``--local-processes``' launcher tabulates the batched rows while the processes still run the
oracle). Interleaved rounds in one process; medians and every round; the tables must be identical.

    python benchmarks/tables_early.py [--run results/table1_synthetic_1000_paper] [--rounds 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import scipy.stats  # noqa: F401  (imported before timing, as the launcher does while its processes run)

from jaxcls import io
from jaxcls.config import load_config
from jaxcls.experiments.table1 import data, tables
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.world.objects import object_set_from_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, default=Path("results/table1_synthetic_1000_paper"),
                        help="a stored run: its config.yaml and labels.jsonl.xz (or episodes.jsonl)")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    store = args.run / "labels.jsonl.xz"
    records = io.read_jsonl(store if store.exists() else args.run / "episodes.jsonl")
    config = load_config(Table1Config, args.run / "config.yaml")
    classes = len(object_set_from_config(data.dataset_config(config).objects).classes)
    keys = [(r["classifier"], r["row"], r["scene"], r["run"]) for r in records]
    alone, early, after = [], [], []
    for _ in range(args.rounds):
        began = time.perf_counter()
        at_the_end = tables.tables(config, records, classes, None, None)
        alone.append(time.perf_counter() - began)
        began = time.perf_counter()
        rows = tables.EarlyRows(config, classes, keys)
        rows.offer(records)
        made = rows.result()
        early.append(time.perf_counter() - began)
        began = time.perf_counter()
        with_rows = tables.tables(config, records, classes, None, None, made)
        after.append(time.perf_counter() - began)
        assert with_rows == at_the_end, "the tables differ"

    def show(seconds: list[float]) -> str:
        return f"{statistics.median(seconds):.2f} s ({', '.join(f'{s:.2f}' for s in seconds)})"

    print(f"{len(records)} records, {len(made)} rows made early: the tables alone at the end {show(alone)}; "
          f"the rows made early {show(early)}; the tables after them {show(after)}; identical tables")


if __name__ == "__main__":
    main()
