# Session 4: the full scale config on one GPU (warm cache /tmp/cache_s) into /tmp/g1; records against /tmp/l4.
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
export PYTHONFAULTHANDLER=1
CACHE=/tmp/cache_s LIMIT=${LIMIT:-590} bash $R/.dev5/s/t1.sh table1_real_like_scale 1 /tmp/g1 \
  scene_chunk=50 oracle_scenes=${ORC:-50} "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
for d in /tmp/l4; do [ -d $d ] && python $R/.dev5/s/cmp2.py /tmp/g1 $d | tee $OUT/r/cmp_$(basename $d).txt; done
tar czf $OUT/g3.tgz -C $OUT r && rm -rf $OUT/r
cp /tmp/g1.log $OUT/g1.log 2>/dev/null
