"""N right after 1, 3, 5 and 10 moves for each row of a Table 1 store (``episodes.jsonl``; N estimated), with the
scene-bootstrap interval of ``counting.count_summary``: ``python count_by_row.py EPISODES.jsonl``."""

import json
import sys
from collections import defaultdict

from jaxcls.experiments.counting import count_summary

rows = defaultdict(list)
with open(sys.argv[1]) as f:
    for line in f:
        r = json.loads(line)
        rows[r["row"]].append({"segments": r["segments"], "objects": r["objects"], "scene": r["scene"]})
print("| row | N right after 1 | after 3 [95% CI] | after 5 | after 10 | errors after 3 |")
print("| --- | --- | --- | --- | --- | --- |")
for row, records in rows.items():
    s = {m: count_summary(records, m, 1000) for m in (1, 3, 5, 10)}
    spread = " ".join(f"{k:+d}:{v}" for k, v in s[3]["spread"].items())
    print(f"| {row} | {s[1]['episodes']:.3f} | {s[3]['episodes']:.3f} [{s[3]['low']:.3f}, {s[3]['high']:.3f}] | "
          f"{s[5]['episodes']:.3f} | {s[10]['episodes']:.3f} [{s[10]['low']:.3f}, {s[10]['high']:.3f}] | {spread} |")
