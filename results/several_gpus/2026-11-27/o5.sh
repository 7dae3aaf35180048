# Call O5: the full scale config on one GPU (warm cache): 1,000 scenes, both classifiers, oracle on ORC scenes.
NOSCENE=1 source .dev4/s/pre.sh
source .dev4/s/run.sh
CACHE=/tmp/cache_s LIMIT=${LIMIT:-590} bash $R/.dev4/s/t1.sh table1_real_like_scale 1 /tmp/g1 \
  scene_chunk=50 oracle_scenes=${ORC:-100} "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
python $R/.dev4/s/cmp2.py /tmp/g1 $(ls -d /tmp/l? 2>/dev/null)
tar czf $OUT/o5.tgz -C $OUT r && rm -rf $OUT/r
