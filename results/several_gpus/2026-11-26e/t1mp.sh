# Table 1, N processes of one GPU each (jax.distributed over localhost), a fresh cache: t1mp.sh CONFIG N OUT [overrides]
cfg=$1; n=$2; out=$3; shift 3
export JAXCLS_CACHE_DIR=${CACHE:-/tmp/cache_$(basename $out)}
t0=$(date +%s.%N)
for i in $(seq 0 $((n - 1))); do
  CUDA_VISIBLE_DEVICES=$i timeout -s KILL ${LIMIT:-560} python experiments/table1.py --config $cfg --distributed --coordinator localhost:$((4300 + n)) \
    --processes $n --process-id $i out_dir=$out "$@" > $out.$i.log 2>&1 &
done
wait
echo "table1 $out ($n processes of 1 GPU): wall $(python -c "import time; print(round(time.time() - $t0, 1))") s"
for i in $(seq 0 $((n - 1))); do tr '\r' '\n' < $out.$i.log | grep -E "run times|episodes in|Error|error:|Traceback" | tail -3; done
name=$(basename $out)
for f in $out/run_times*.json; do cp $f $OUT/r/${name}_$(basename $f); done 2>/dev/null
cp $out/table.md $OUT/r/${name}_table.md 2>/dev/null; cat $out/episodes*.jsonl | wc -l
