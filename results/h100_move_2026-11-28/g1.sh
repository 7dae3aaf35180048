#!/usr/bin/env bash
# Blocks sweep (kernels alone) + whole move at HEAD, one GPU.
set -o pipefail
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
git rev-parse --short HEAD 2>/dev/null
python benchmarks/pallas_kernels.py --batch 512 --repeats 5 \
  --fusion-blocks 2048w4 1024w4 4096w4 4096w8 8192w8 2048w4s4 8192w8s4 32768w8s16 \
  --pool-blocks 128x64w4 128x32w4 128x64w4a 256x32w8 256x64w8a 128x64w4g2 128x64w4g4a 64x64w4 \
  --out $OUT/sweep.md 2>&1 | tee $OUT/sweep.log | grep -v Warning
python benchmarks/episode_batched.py --frames .dev5/scene3.npz --batch 512 --repeats 3 --storage compact \
  --precision bfloat16 --fusion xla pallas --pooling xla pallas --tracking-levels 1 --trace $OUT/trace512.json \
  --out $OUT/eb512.md 2>&1 | tee $OUT/eb512.log | grep -v Warning | tail -20
