# Table 1 with --local-processes N: tl.sh CONFIG N OUT [overrides]; CACHE env: the compilation cache; LIMIT env: seconds.
cfg=$1; n=$2; out=$3; shift 3
export JAXCLS_CACHE_DIR=${CACHE:-/tmp/cache_$(basename $out)}
/usr/bin/time -f "table1 $out (--local-processes $n): wall %e s" timeout ${LIMIT:-560} python experiments/table1.py \
  --config $cfg out_dir=$out "$@" --local-processes $n > $out.log 2>&1
tr '\r' '\n' < $out.log | grep -E "run times|wall|episodes in|Error|error:|Traceback" | tail -5
for i in $(seq 0 $((n - 1))); do tr '\r' '\n' < $out/process.$i.log | grep -E "run times|Error|Traceback" | tail -2; done
name=$(basename $out)
for f in $out/run_times*.json; do cp $f $OUT/r/${name}_$(basename $f); done 2>/dev/null
cp $out/table.md $OUT/r/${name}_table.md 2>/dev/null; cat $out/episodes*.jsonl | wc -l
