# Session 6: issue 34's tracking pyramid A/B (2 levels vs 1) at 512 episodes, bfloat16, frames in memory, one GPU.
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.95
timeout ${LIMIT:-400} python benchmarks/episode_batched.py --frames $R/.dev5/scene3.npz --batch ${B:-512} --repeats 3 \
  --storage compact --precision bfloat16 --tracking-levels 2 1 --trace $OUT/r/trace.json --out $OUT/r/eb_levels.md 2>&1 | grep -v Warning | tail -14
tar czf $OUT/g7.tgz -C $OUT r && rm -rf $OUT/r
