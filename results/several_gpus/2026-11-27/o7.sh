# Call O7: --local-processes N (N env), compiles logged (which programs a process compiles or loads), cache listed.
NOSCENE=1 source .dev4/s/pre.sh
source .dev4/s/run.sh
ls /tmp/cache_s | wc -l; echo since g1: ; find /tmp/cache_s -type f -newer /tmp/g1/table.md | cut -c1-120; touch /tmp/mark
export JAX_LOG_COMPILES=1
CACHE=/tmp/cache_s LIMIT=${LIMIT:-560} bash $R/.dev4/s/tl.sh table1_real_like_scale $N /tmp/l$N \
  scene_chunk=50 oracle_scenes=${ORC:-100} "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
[ -d /tmp/g1 ] && python $R/.dev4/s/cmp2.py /tmp/g1 /tmp/l$N
ls /tmp/cache_s | wc -l; echo new entries: $(find /tmp/cache_s -type f -newer /tmp/mark | wc -l); ls -lt /tmp/cache_s | head -8
for i in $(seq 0 $((N - 1))); do tr '\r' '\n' < /tmp/l$N/process.$i.log | grep -iE "finished xla compilation|cache (hit|miss)|persistent" > $OUT/r/compiles.$i.txt; done
grep -ciE "finished xla compilation" $OUT/r/compiles.*.txt; grep -iE "finished xla compilation" $OUT/r/compiles.0.txt | awk '{for(i=1;i<=NF;i++) if($i=="in") print $(i+1), $0}' | sort -rn | head -12 | cut -c1-250
tar czf $OUT/o7_$N.tgz -C $OUT r && rm -rf $OUT/r
