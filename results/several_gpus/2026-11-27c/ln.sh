# --local-processes N for each N in NS (env), warm; each compared with the one-GPU run (records).
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
for N in ${NS:-2 4}; do
  CACHE=/tmp/cache_s LIMIT=${LIMIT:-300} bash $R/.dev5/s/tl.sh table1_real_like_scale $N /tmp/l$N \
    scene_chunk=50 oracle_scenes=${ORC:-50} "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
  [ -d /tmp/g1 ] && python $R/.dev5/s/cmp2.py /tmp/g1 /tmp/l$N | tee $OUT/r/cmp_l$N.txt
done
tar czf $OUT/ln.tgz -C $OUT r && rm -rf $OUT/r
