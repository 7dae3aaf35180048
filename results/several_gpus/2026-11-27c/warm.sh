# The last warp part, then the warm-up of the full scale config (both classifiers, the oracle's 50-scene calls):
# 100 scenes, the oracle on 50: every shape the later runs use, compiled into /tmp/cache_s.
NOSCENE=1 source .dev5/s/pre.sh
bash .dev5/s/w.sh $P || exit 1
source .dev5/s/run.sh
CACHE=/tmp/cache_s LIMIT=${LIMIT:-520} bash $R/.dev5/s/t1.sh table1_real_like_scale 1 /tmp/warm \
  scene_chunk=50 scenes=100 oracle_scenes=50 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
tar czf $OUT/warm.tgz -C $OUT r && rm -rf $OUT/r
