"""Which of a process share's oracle records (/tmp/q_B) differ from one process's (/tmp/q_A): their call and place in
it (episodes of a classifier in (scene, run) order, 64 a call), and the fields that differ in the first."""
import json
from pathlib import Path


def load(folder):
    out = {}
    for f in sorted(Path(folder).glob("episodes*.jsonl")):
        for line in open(f):
            r = json.loads(line)
            out[(r["classifier"], r["row"], r["scene"], r["run"])] = r
    return out


A, B = load("/tmp/q_A"), load("/tmp/q_B")
keys = sorted(k for k in A if k[1] == "oracle_gr")
classifiers = sorted({k[0] for k in keys})
print("classifiers", classifiers, "episodes", len(keys))
place = {}
for c in classifiers:
    for i, k in enumerate(sorted((k for k in keys if k[0] == c), key=lambda k: (k[2], k[3]))):
        place[k] = (c, i // 64, i % 64)
differ = [k for k in B if A[k] != B[k]]
print("B calls:", sorted({place[k][:2] for k in B}))
print("differ:", sorted(place[k] for k in differ))
if differ:
    a, b = A[differ[0]], B[differ[0]]
    print("fields differing in", differ[0], [f for f in a if a[f] != b.get(f)])
    for f in a:
        if a[f] != b.get(f):
            print(f, str(a[f])[:300], "|", str(b[f])[:300])
