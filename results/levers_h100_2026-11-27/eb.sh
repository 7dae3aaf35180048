# Issue 34's levers A/B at 512 episodes on one GPU: slabs 1/8 x segments a pass 1/5 x PointNet tf32/bfloat16.
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.95
timeout ${LIMIT:-470} python benchmarks/episode_batched.py --frames $R/.dev5/scene3.npz --batch ${B:-512} --repeats 3 \
  --storage compact --precision tf32 bfloat16 --slabs 1 8 --segments-per-pass 1 5 --out $OUT/r/eb.md 2>&1 | grep -v Warning | tail -14
tar czf $OUT/eb.tgz -C $OUT r && rm -rf $OUT/r
