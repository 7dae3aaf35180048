# The full scale config on one GPU (warm cache): 1,000 scenes, both classifiers, the oracle on ORC scenes.
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
CACHE=/tmp/cache_s LIMIT=${LIMIT:-590} bash $R/.dev5/s/t1.sh table1_real_like_scale 1 /tmp/g1 \
  scene_chunk=50 oracle_scenes=${ORC:-50} "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
tar czf $OUT/g1.tgz -C $OUT r && rm -rf $OUT/r
