import json, sys
from pathlib import Path
def load(p):
    out = {}
    for f in sorted(Path(p).glob("episodes*.jsonl")):
        for line in open(f):
            r = json.loads(line); out[(r["classifier"], r["row"], r["scene"], r["run"])] = r
    return out
A, B = load("/tmp/q_A"), load("/tmp/q_B")
keys = sorted(k for k in A if k[1] == "oracle_gr")
order = sorted(keys, key=lambda k: (k[0] != sorted({x[0] for x in keys})[0], k[2], k[3]))
cls = sorted({k[0] for k in keys}); print("classifiers", cls, "episodes", len(keys))
idx = {}
for c in cls:
    ks = [k for k in keys if k[0] == c]
    ks.sort(key=lambda k: (k[2], k[3]))
    for i, k in enumerate(ks): idx[k] = (c, i // 64, i % 64)
diff = [k for k in B if A[k] != B[k]]
print("B calls:", sorted({idx[k][:2] for k in B}))
print("differ:", sorted(idx[k] for k in diff))
k = diff[0]; a, b = A[k], B[k]
print("fields differing in", k, [f for f in a if a[f] != b.get(f)])
for f in a:
    if a[f] != b.get(f): print(f, str(a[f])[:300], "|", str(b[f])[:300])
