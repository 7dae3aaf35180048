# PointNet's folded pooling: the product laid out channels x points (src, HEAD) against points x channels (srcB),
# alternating processes, 512 episodes, bfloat16, the scale layout.
NOSCENE=1 source .dev5/s/pre.sh
R=$PWD; export XLA_PYTHON_CLIENT_MEM_FRACTION=0.95
for w in .dev5/src .dev5/srcB; do [ -f $w/jaxcls/perception/weights/pointnet_builtin.msgpack ] || cp jaxcls/perception/weights/*.msgpack $w/jaxcls/perception/weights/; done
for i in 1 2; do for v in src srcB; do
  (cd .dev5/$v && PYTHONPATH=/tmp/site:$PWD timeout 80 python benchmarks/episode_batched.py --frames $R/.dev5/scene3.npz \
     --batch 512 --repeats 3 --storage compact --slabs 8 --segments-per-pass 1 --precision bfloat16 \
     --out $OUT/r/ab3_${v}_$i.md 2>&1 | grep "^| 512" | sed "s/^/$v $i: /")
done; done
tar czf $OUT/ab3.tgz -C $OUT r && rm -rf $OUT/r
