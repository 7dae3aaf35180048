# Call N2: --local-processes N (default 4) over the scale config, warm (the one-GPU run's cache).
source .dev4/s/pre.sh
CACHE=/tmp/cache_s LIMIT=400 bash .dev4/s/tl.sh table1_real_like_scale ${N:-4} /tmp/l${N:-4} "classifiers={paper: builtin_paper}" \
  scene_chunk=50 oracle_scenes=0 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
[ -d /tmp/g1 ] && python .dev4/s/cmp2.py /tmp/g1 /tmp/l${N:-4}
tar czf $OUT/n2_${N:-4}.tgz -C $OUT r && rm -rf $OUT/r
