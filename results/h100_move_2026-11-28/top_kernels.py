"""The kernels of a kept profile (``benchmarks/profile_batched.py --keep DIR``), each by its HLO op name, the
largest first: ``python top_kernels.py DIR/perfetto_trace.json.gz DIR/<module>_after_optimizations.txt``."""

import collections
import gzip
import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from profile_batched import op_names

names = op_names(Path(sys.argv[2]).read_text())
events = json.load(gzip.open(sys.argv[1], "rt"))["traceEvents"]
gpu = {e["pid"] for e in events if e.get("ph") == "M" and e.get("name") == "process_name"
       and "/device:GPU" in e["args"]["name"]}
times: collections.Counter = collections.Counter()
counts: collections.Counter = collections.Counter()
for e in events:
    if e.get("ph") != "X" or e["pid"] not in gpu:
        continue
    name = re.sub(r"jit\(_one\)/", "", names.get(e.get("args", {}).get("hlo_op", ""), "?"))
    key = (name[-150:], e["name"][:40])
    times[key] += e["dur"] / 1e3
    counts[key] += 1
total = sum(times.values())
print("total kernel ms a call", round(total, 1))
for key, ms in times.most_common(45):
    print(f"{ms:7.1f} {100 * ms / total:5.1f}% n={counts[key]:5d} {key[1]:40s} {key[0]}")
