# Issue 34: 45f59e8 (srcA) against HEAD (src: PointNet's pooled MLPs folded, segment_jax's scatters) in
# alternating processes, 512 episodes, the scale layout, PointNet bfloat16 and TF32; traces of round 1 kept.
NOSCENE=1 source .dev5/s/pre.sh
R=$PWD; export XLA_PYTHON_CLIENT_MEM_FRACTION=0.95
for w in .dev5/src .dev5/srcA; do [ -f $w/jaxcls/perception/weights/pointnet_builtin.msgpack ] || cp jaxcls/perception/weights/*.msgpack $w/jaxcls/perception/weights/; done
for i in 1 2; do for v in srcA src; do
  tr=""; [ $i = 1 ] && tr="--trace $OUT/r/trace_$v.json"
  (cd .dev5/$v && PYTHONPATH=/tmp/site:$PWD timeout 200 python benchmarks/episode_batched.py --frames $R/.dev5/scene3.npz \
     --batch ${B:-512} --repeats 3 --storage compact --slabs 8 --segments-per-pass 1 --precision bfloat16 tf32 $tr \
     --out $OUT/r/ab_${v}_$i.md 2>&1 | grep "^| ${B:-512}" | sed "s/^/$v $i: /")
done; done
python - <<'PY'
import json, os
o = os.environ["OUT"] + "/r"
a, b = (json.load(open(f"{o}/trace_{v}.json")) for v in ("srcA", "src"))
for va in ("bfloat16", "tf32"):
    A = [t for t in a if t["variant"] == va]; B = [t for t in b if t["variant"] == va]
    same = sum(x["path"] == y["path"] and x["refined"] == y["refined"] for x, y in zip(A, B))
    print(f"{va}: {same} of {len(A)} episodes same path and labels (srcA vs src)")
PY
tar czf $OUT/ab2.tgz -C $OUT r && rm -rf $OUT/r
