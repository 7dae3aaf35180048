# One H200: whole moves/s at 512 episodes, frames in memory, the scale layout, both Pallas kernels (code d2ab00d).
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 MPLBACKEND=Agg
nvidia-smi --query-gpu=name --format=csv,noheader
timeout 330 python benchmarks/episode_batched.py --frames .dev5/scene3.npz --batch 512 --repeats 5 --storage compact \
  --precision bfloat16 --fusion pallas --pooling pallas --tracking-levels 1 --out $OUT/mv_h200.md 2>&1 | grep -v Warn | tail -15
