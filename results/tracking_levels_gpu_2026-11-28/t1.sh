# Table 1, one process on the first N GPUs: t1.sh CONFIG N OUT [overrides]; CACHE env: the compilation cache
# (default a fresh one named after OUT); LIMIT env: seconds.
cfg=$1; n=$2; out=$3; shift 3
export JAXCLS_CACHE_DIR=${CACHE:-/tmp/cache_$(basename $out)}
CUDA_VISIBLE_DEVICES=${GPUS:-$(seq -s, 0 $((n - 1)))} /usr/bin/time -f "table1 $out (1 process, $n GPUs): wall %e s" \
  timeout ${LIMIT:-560} python experiments/table1.py --config $cfg out_dir=$out "$@" > $out.log 2>&1
tr '\r' '\n' < $out.log | grep -E "run times|wall|episodes in|Error|error:|Traceback" | tail -5
name=$(basename $out)
for f in $out/run_times*.json; do cp $f $OUT/r/${name}_$(basename $f); done 2>/dev/null
cp $out/table.md $OUT/r/${name}_table.md 2>/dev/null; cat $out/episodes*.jsonl | wc -l
