"""Compare Table 1 runs (folders of episodes*.jsonl): identical records overall and per row; for records that
differ, the first move where the path or the refined labels part."""
import json
import sys
from collections import Counter
from pathlib import Path


def load(p):
    out = {}
    for f in sorted(Path(p).glob("episodes*.jsonl")):
        for line in open(f):
            r = json.loads(line)
            out[(r["classifier"], r["row"], r["scene"], r["run"])] = r
    return out
base = load(sys.argv[1])
for other in sys.argv[2:]:
    b = load(other)
    keys = sorted(set(base) & set(b))
    rows = Counter(k[1] for k in keys)
    same = Counter(k[1] for k in keys if base[k] == b[k])
    first = Counter()
    for k in keys:
        if base[k] != b[k]:
            x, y = base[k], b[k]
            prior_x, prior_y = x.get("prior", [None] * 99), y.get("prior", [None] * 99)
            m = next((i for i in range(len(x["path"])) if x["path"][i] != y["path"][i]
                      or x["refined"][i] != y["refined"][i] or prior_x[i] != prior_y[i]), None)
            first[m] += 1
    print(f"{sys.argv[1]} vs {other}: {len(base)} vs {len(b)} records, {len(keys)} shared, identical "
          f"{sum(same.values())}; per row: " + ", ".join(f"{r} {same[r]}/{n}" for r, n in rows.items())
          + f"; first differing move: {dict(sorted(first.items(), key=str))}")
