# After g12: whole warm runs of experiments/table1.py, A/B/C alternating, 2 rounds (marks_s of run_times.json).
source .dev5/s/pre.sh || exit 1
O="scenes=50 oracle_scenes=0 scene_chunk=50 dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
envof() { case $1 in A) echo "X=1";; B) echo "JAX_TRACEBACK_IN_LOCATIONS_LIMIT=0";; C) echo "JAX_INCLUDE_FULL_TRACEBACKS_IN_LOCATIONS=false";; esac; }
for r in 1 2; do for S in A B C; do
  rm -rf /tmp/w$S$r; env $(envof $S) JAXCLS_CACHE_DIR=/tmp/x$S timeout 120 python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/w$S$r $O > $OUT/r/w_${S}_$r.log 2>&1
  echo "warm $S $r rc $?: $(tr '\r' '\n' < $OUT/r/w_${S}_$r.log | grep 'run times' | tail -1 | grep -o 'devices ready.*')"
  cp /tmp/w$S$r/run_times.json $OUT/r/t_${S}_$r.json 2>/dev/null
  python - $S $r <<'PY'
import json, sys, glob
S, r = sys.argv[1:]
import hashlib
for f in sorted(glob.glob(f"/tmp/w{S}{r}/*.jsonl")):
    print(" ", f.split('/')[-1], hashlib.sha256(open(f,'rb').read()).hexdigest()[:16])
PY
done; done
tar czf $OUT/g12b.tgz -C $OUT r && rm -rf $OUT/r
