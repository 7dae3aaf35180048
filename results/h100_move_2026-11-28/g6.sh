#!/usr/bin/env bash
# Whole move A/B on one GPU: A = d4a6003's tsdf.py and pointnet.py over a copy of the tree, B = the tree
# (the GPU's word-of-slot pass in the surface extraction; the pooling kernel's max once at the end). A, B, A, B.
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name --format=csv,noheader
rm -rf /tmp/srcA && mkdir -p /tmp/srcA && cp -r jaxcls benchmarks pyproject.toml /tmp/srcA/ && cp -r .dev5/oldB/* /tmp/srcA/
mkdir -p $OUT/ab
EB="benchmarks/episode_batched.py --frames $PWD/.dev5/scene3.npz --batch 512 --repeats 3 --storage compact --precision bfloat16 --fusion pallas --pooling pallas --tracking-levels 1"
for r in 1 2; do
  (cd /tmp/srcA && PYTHONPATH=/tmp/site:/tmp/srcA timeout 140 python $EB --trace $OUT/ab/traceA$r.json --out $OUT/ab/A$r.md 2>&1 | grep "^(512")
  PYTHONPATH=/tmp/site:$PWD timeout 140 python $EB --trace $OUT/ab/traceB$r.json --out $OUT/ab/B$r.md 2>&1 | grep "^(512"
done
cmp $OUT/ab/traceA1.json $OUT/ab/traceB1.json && echo "traces A1 B1 identical"
cmp $OUT/ab/traceA1.json $OUT/ab/traceA2.json && echo "traces A1 A2 identical"
cd $OUT && tar -cJf ab.tar.xz ab && rm -rf ab
