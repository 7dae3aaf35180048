# Call M2: the scale config (paper weights, 1,000 real-like scenes x 10 runs, 10 rows + the oracle on 100) on 1 GPU, warm.
source .dev4/s/pre.sh
CACHE=/tmp/cache_s LIMIT=${L1:-590} bash .dev4/s/t1.sh table1_real_like_scale 1 /tmp/g1 "classifiers={paper: builtin_paper}" \
  scene_chunk=50 oracle_scenes=${ORC:-0} "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
cat /tmp/g1/run_times.json
tar czf $OUT/m2.tgz -C $OUT r && rm -rf $OUT/r
