# Issue 34: the fused small products (8e42683) A/B in alternating processes: srcA (c75f88e) against src (HEAD),
# 512 episodes, PointNet in bfloat16 and TF32, the scale layout; frames of scene 3 (.dev5/scene3.npz).
NOSCENE=1 source .dev5/s/pre.sh
R=$PWD; export XLA_PYTHON_CLIENT_MEM_FRACTION=0.95
for w in .dev5/src .dev5/srcA; do [ -f $w/jaxcls/perception/weights/pointnet_builtin.msgpack ] || cp jaxcls/perception/weights/*.msgpack $w/jaxcls/perception/weights/; done
for i in 1 2; do for v in srcA src; do
  (cd .dev5/$v && PYTHONPATH=/tmp/site:$PWD timeout 200 python benchmarks/episode_batched.py --frames $R/.dev5/scene3.npz \
     --batch ${B:-512} --repeats 3 --storage compact --precision bfloat16 tf32 --out $OUT/r/ab_${v}_$i.md 2>&1 \
     | grep "^| ${B:-512}" | sed "s/^/$v $i: /")
done; done
tar czf $OUT/ab.tgz -C $OUT r && rm -rf $OUT/r
