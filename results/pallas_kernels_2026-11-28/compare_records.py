"""Compare Table 1 runs (folders of episodes*.jsonl): records identical overall and per row; for records that
differ, the first move where the path or the labels part.

    python results/pallas_kernels_2026-11-28/compare_records.py RUN_A RUN_B [RUN_C ...]
"""

import json
import sys
from collections import Counter
from pathlib import Path


def load(folder: str) -> dict:
    out = {}
    for f in sorted(Path(folder).glob("episodes*.jsonl")):
        for line in open(f):
            r = json.loads(line)
            out[(r["classifier"], r["row"], r["scene"], r["run"])] = r
    return out


def main() -> None:
    base = load(sys.argv[1])
    for other in sys.argv[2:]:
        b = load(other)
        keys = sorted(set(base) & set(b))
        rows = Counter(k[1] for k in keys)
        same = Counter(k[1] for k in keys if base[k] == b[k])
        first: Counter = Counter()
        for k in keys:
            x, y = base[k], b[k]
            if x != y:
                first[next((i for i in range(len(x["path"])) if x["path"][i] != y["path"][i]
                            or x["refined"][i] != y["refined"][i] or x["prior"][i] != y["prior"][i]), None)] += 1
        print(f"{sys.argv[1]} vs {other}: {len(base)} vs {len(b)} records, {len(keys)} shared, identical "
              f"{sum(same.values())}; per row: " + ", ".join(f"{r} {same[r]}/{n}" for r, n in rows.items())
              + f"; first differing move: {dict(sorted(first.items(), key=str))}")


if __name__ == "__main__":
    main()
