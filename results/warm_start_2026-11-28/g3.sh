#!/usr/bin/env bash
# Warm start on one GPU, new code: settings exported (runtime on a thread) vs runtime_later; timeline.
set -o pipefail
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name --format=csv,noheader
timeout 560 python benchmarks/first_call.py --config table1_real_like_scale --settings exported runtime_later --rounds 2 \
  --out $OUT/fc_new.md scenes=50 oracle_scenes=0 scene_chunk=50 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]" \
  2>&1 | grep -v "Warning\|warn" | tail -24
