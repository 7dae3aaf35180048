# Call O4: the last warp part; warm-up of the full scale config (both classifiers, the oracle's 50-scene frames):
# 100 scenes, the oracle on 50 (its chunk of 50 scenes' frames: the shape every later run uses).
NOSCENE=1 source .dev4/s/pre.sh
bash .dev4/s/w.sh .dev4/w.3 || exit 1
source .dev4/s/run.sh
CACHE=/tmp/cache_s LIMIT=${LIMIT:-560} bash $R/.dev4/s/t1.sh table1_real_like_scale 1 /tmp/warm \
  scene_chunk=50 scenes=100 oracle_scenes=50 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
tr '\r' '\n' < /tmp/warm.log | grep -E "oracle" | tail -3
tar czf $OUT/o4.tgz -C $OUT r && rm -rf $OUT/r
