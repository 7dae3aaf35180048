# Table 1 with --local-processes N: tl.sh N OUT [overrides]; CACHE env: the compilation cache; LIMIT env: seconds.
n=$1; out=$2; shift 2
export JAXCLS_CACHE_DIR=${CACHE:-/tmp/cache_s}
/usr/bin/time -f "table1 $out (--local-processes $n): wall %e s" timeout ${LIMIT:-560} python experiments/table1.py \
  --config table1_real_like_scale out_dir=$out scene_chunk=50 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]" "$@" --local-processes $n > $out.log 2>&1
tr '\r' '\n' < $out.log | grep -E "run times|wall|episodes in|Error|error:|Traceback" | tail -5
for i in $(seq 0 $((n - 1))); do tr '\r' '\n' < $out/process.$i.log | grep -E "Error|Traceback" | tail -2; done
name=$(basename $out)
for f in $out/run_times*.json; do cp $f $OUT/r/${name}_$(basename $f); done 2>/dev/null
cp $out/table.md $OUT/r/${name}_table.md 2>/dev/null; cat $out/episodes*.jsonl | wc -l
