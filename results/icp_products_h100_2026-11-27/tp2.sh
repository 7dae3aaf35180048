# Issue 34: rendered 4096 (F4 pool fraction) with src (HEAD) and srcD (depth-only render), alternating processes.
NOSCENE=1 source .dev5/s/pre.sh
cp jaxcls/perception/weights/*.msgpack .dev5/srcD/jaxcls/perception/weights/ 2>/dev/null; (cd .dev5/srcD && PYTHONPATH=/tmp/site:$PWD timeout 120 python $OLDPWD/.dev5/s/dq.py $OLDPWD/.dev5/scene3.npz 2>&1 | grep -v Warn | tail -4)
R=$PWD; export XLA_PYTHON_CLIENT_MEM_FRACTION=${F4:-0.66}
for w in .dev5/src .dev5/srcD; do [ -f $w/jaxcls/perception/weights/pointnet_builtin.msgpack ] || cp jaxcls/perception/weights/*.msgpack $w/jaxcls/perception/weights/; done
for i in ${ROUNDS:-1}; do for v in ${VARIANTS:-srcD src}; do
  (cd .dev5/$v && PYTHONPATH=/tmp/site:$PWD timeout ${LIMIT:-270} python benchmarks/episode_batched.py --frames $R/.dev5/scene3.npz \
     --render --batch ${B:-4096} --repeats 3 --storage compact --precision bfloat16 --slabs 8 --segments-per-pass 1 \
     --out $OUT/r/tp_${v}_$i.md > /tmp/tp_${v}_$i.log 2>&1; echo "rc $? $v $i"; grep "^| ${B:-4096}" /tmp/tp_${v}_$i.log | sed "s/^/$v $i: /"; cp /tmp/tp_${v}_$i.log $OUT/r/)
done; done
tar czf $OUT/tp2.tgz -C $OUT r && rm -rf $OUT/r
