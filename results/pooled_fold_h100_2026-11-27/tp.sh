# Issue 34 throughput: rendered vs pre-rendered, bf16 + fused, the scale layout, 2048 and 4096 (separate processes).
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh

for b in ${BATCHES:-2048 4096}; do
  [ $b = 4096 ] && export XLA_PYTHON_CLIENT_MEM_FRACTION=${F4:-0.82}
  timeout ${LIMIT:-280} python benchmarks/episode_batched.py --frames $R/.dev5/scene3.npz --render --batch $b --repeats 3 \
    --storage compact --precision bfloat16 --slabs 8 --segments-per-pass 1 --out $OUT/r/tp_$b.md > /tmp/tp_$b.log 2>&1
  echo "rc $? batch $b"; grep -v Warning /tmp/tp_$b.log | tail -12; cp /tmp/tp_$b.log $OUT/r/
done
tar czf $OUT/tp.tgz -C $OUT r && rm -rf $OUT/r
