"""PointNet in one precision against another (perception.classification_precision: float32 or tf32 against
bfloat16), Table 1's episodes on the same scenes, start views and keys: each row's F1 after T, the paired
difference (scene bootstrap), and the share of episodes with the same path and refined labels. The columns are
named by each run's config.yaml.

    python results/bf16_table1_synthetic_50/compare.py runs/bf16_ab/float32 runs/bf16_ab/bfloat16
"""

import sys
from pathlib import Path

import numpy as np

from jaxcls import metrics
from jaxcls.config import load_config
from jaxcls.episode import protocol
from jaxcls.experiments.counting import paired_runs
from jaxcls.experiments.table1 import data
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.perception import pointnet

a_dir, b_dir = map(Path, sys.argv[1:3])
a, b = (data.read_stores(d / "episodes.jsonl") for d in (a_dir, b_dir))
M = len(pointnet.load_classifier().classes)  # the shipped weights' (the runs' classifier)
pa, pb = (load_config(Table1Config, d / "config.yaml").perception.classification_precision for d in (a_dir, b_dir))
print(f"| row | scenes | episodes | F1 {pa} | F1 {pb} | {pb} - {pa} [95% paired scene interval] | "
      "same path and refined labels |")
print("| --- | --- | --- | --- | --- | --- | --- |")
for (_, row), (x, y) in paired_runs(a, b).items():
    T = max(len(r["refined"]) for r in x)
    sa, sb = protocol.scene_labels(x).at(T), protocol.scene_labels(y).at(T)
    f = [metrics.classification_scores(np.concatenate([t for t, _ in s]), np.concatenate([p for _, p in s]), M).f1
         for s in (sa, sb)]
    d = metrics.paired_difference(sb, sa, M)
    same = np.mean([p["path"] == q["path"] and p["refined"] == q["refined"] for p, q in zip(x, y, strict=True)])
    print(f"| {row} | {len(sa)} | {len(x)} | {f[0]:.3f} | {f[1]:.3f} | {metrics.format_difference(*d)} | {same:.2f} |")
