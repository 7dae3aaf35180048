# Issue 34: the fusion's slabs batched in place (srcB: tsdf.slabs_in_place) against HEAD (src), alternating processes,
# 512 episodes, bf16, frames in memory; traces of round 1 compared; then a kernel profile of srcB.
NOSCENE=1 source .dev5/s/pre.sh
R=$PWD; export XLA_PYTHON_CLIENT_MEM_FRACTION=0.95
mkdir -p $OUT/ab
for w in .dev5/src .dev5/srcB; do [ -f $w/jaxcls/perception/weights/pointnet_builtin.msgpack ] || cp jaxcls/perception/weights/*.msgpack $w/jaxcls/perception/weights/; done
for i in 1 2; do for v in src srcB; do
  tr=""; [ $i = 1 ] && tr="--trace $OUT/ab/trace_$v.json"
  (cd .dev5/$v && PYTHONPATH=/tmp/site:$PWD timeout 150 python benchmarks/episode_batched.py --frames $R/.dev5/scene3.npz \
     --batch 512 --repeats 3 --storage compact --precision bfloat16 $tr \
     --out $OUT/ab/ab_${v}_$i.md 2>&1 | grep "^| 512" | sed "s/^/$v $i: /")
done; done | tee $OUT/ab/summary.txt
python - <<'PY' | tee -a $OUT/ab/summary.txt
import json, os
o = os.environ["OUT"] + "/ab"
a, b = (json.load(open(f"{o}/trace_{v}.json")) for v in ("src", "srcB"))
same = sum(x["path"] == y["path"] and x["refined"] == y["refined"] for x, y in zip(a, b))
print(f"srcB vs src: {same} of {len(a)} episodes same path and labels")
PY
(cd .dev5/srcB && PYTHONPATH=/tmp/site:$PWD timeout 200 python benchmarks/profile_batched.py --frames $R/.dev5/scene3.npz --batch 512 \
   --keep /tmp/profB --out $OUT/ab/profB.md 2>&1 | grep -v Warn | tail -30)
cp /tmp/profB/* $OUT/ab/
tar czf $OUT/ab6.tgz -C $OUT ab && rm -rf $OUT/ab
