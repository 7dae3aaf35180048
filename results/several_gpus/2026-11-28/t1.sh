# Table 1, one process on GPU 0: t1.sh OUT [overrides]; CACHE env; LIMIT env.
out=$1; shift 1
export JAXCLS_CACHE_DIR=${CACHE:-/tmp/cache_s}
CUDA_VISIBLE_DEVICES=0 /usr/bin/time -f "table1 $out (1 process, 1 GPU): wall %e s" timeout ${LIMIT:-560} python experiments/table1.py \
  --config table1_real_like_scale out_dir=$out scene_chunk=50 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]" "$@" > $out.log 2>&1
tr '\r' '\n' < $out.log | grep -E "run times|wall|episodes in|Error|error:|Traceback" | tail -5
name=$(basename $out)
for f in $out/run_times*.json; do cp $f $OUT/r/${name}_$(basename $f); done 2>/dev/null
cp $out/table.md $OUT/r/${name}_table.md 2>/dev/null; cat $out/episodes*.jsonl | wc -l
