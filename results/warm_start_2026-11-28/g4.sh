#!/usr/bin/env bash
# Warm start on one GPU, HEAD's code (d4a6003: the four files of .dev5/old over a copy of the tree).
set -o pipefail
rm -rf /tmp/srcA && mkdir -p /tmp/srcA && cp -r jaxcls experiments benchmarks pyproject.toml /tmp/srcA/ && cp -r .dev5/old/* /tmp/srcA/
cd /tmp/srcA
export PYTHONPATH=/tmp/site:/tmp/srcA PYTHONUNBUFFERED=1
timeout 560 python benchmarks/first_call.py --config table1_real_like_scale --settings exported --rounds 2 \
  --out $OUT/fc_head.md scenes=50 oracle_scenes=0 scene_chunk=50 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]" \
  2>&1 | grep -v "Warning\|warn" | tail -14
