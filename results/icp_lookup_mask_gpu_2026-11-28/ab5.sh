# Issue 34: the ICP lookup A/B on a GPU: srcA (7c60c2d^: the mask gathered) / src (HEAD: points only) / srcB (HEAD +
# hop_points.patch), alternating processes, 512 episodes, bf16, frames in memory; traces of round 1 compared.
R=$PWD; export XLA_PYTHON_CLIENT_MEM_FRACTION=0.95 CUDA_VISIBLE_DEVICES=${GPU:-0}
mkdir -p $OUT/ab
for w in .dev5/src .dev5/srcA .dev5/srcB; do [ -f $w/jaxcls/perception/weights/pointnet_builtin.msgpack ] || cp jaxcls/perception/weights/*.msgpack $w/jaxcls/perception/weights/; done
for i in 1 2; do for v in srcA src srcB; do
  tr=""; [ $i = 1 ] && tr="--trace $OUT/ab/trace_$v.json"
  (cd .dev5/$v && PYTHONPATH=/tmp/site:$PWD timeout 150 python benchmarks/episode_batched.py --frames $R/.dev5/scene3.npz \
     --batch ${B:-512} --repeats 3 --storage compact --precision bfloat16 $tr \
     --out $OUT/ab/ab_${v}_$i.md 2>&1 | grep "^| ${B:-512}" | sed "s/^/$v $i: /")
done; done | tee $OUT/ab/summary.txt
python - <<'PY' | tee -a $OUT/ab/summary.txt
import json, os
o = os.environ["OUT"] + "/ab"
t = {v: json.load(open(f"{o}/trace_{v}.json")) for v in ("srcA", "src", "srcB")}
for v in ("src", "srcB"):
    same = sum(x["path"] == y["path"] and x["refined"] == y["refined"] for x, y in zip(t["srcA"], t[v]))
    print(f"{v} vs srcA: {same} of {len(t[v])} episodes same path and labels")
PY
