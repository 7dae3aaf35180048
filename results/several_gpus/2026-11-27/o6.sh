# Call O6: --local-processes N (N env) over the full scale config, warm; compared with the one-GPU run.
NOSCENE=1 source .dev4/s/pre.sh
source .dev4/s/run.sh
CACHE=/tmp/cache_s LIMIT=${LIMIT:-560} bash $R/.dev4/s/tl.sh table1_real_like_scale $N /tmp/l$N \
  scene_chunk=50 oracle_scenes=${ORC:-100} "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
[ -d /tmp/g1 ] && python $R/.dev4/s/cmp2.py /tmp/g1 /tmp/l$N
tar czf $OUT/o6_$N.tgz -C $OUT r && rm -rf $OUT/r
