# Session 4 (issue 38, programs loaded ahead + early launcher start): warm-up of the scale config's shapes (50
# scenes, the oracle on 50) into /tmp/cache_s, then --local-processes 4 (warm) into /tmp/l4.
NOSCENE=1 source .dev5/s/pre.sh
export PYTHONFAULTHANDLER=1
source .dev5/s/run.sh
CACHE=/tmp/cache_s LIMIT=${WLIMIT:-300} bash $R/.dev5/s/t1.sh table1_real_like_scale 1 /tmp/warm \
  scene_chunk=50 scenes=50 oracle_scenes=50 'classifiers={paper: builtin_paper}' "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
for N in ${NS:-4}; do
  CACHE=/tmp/cache_s LIMIT=${LIMIT:-280} bash $R/.dev5/s/tl.sh table1_real_like_scale $N /tmp/l$N \
    scene_chunk=50 oracle_scenes=${ORC:-50} "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
done
cp /tmp/warm.log /tmp/l4.log $OUT/r/ 2>/dev/null; cp /tmp/l4/process.0.log $OUT/r/l4_process.0.log 2>/dev/null
tar czf $OUT/g2.tgz -C $OUT r && rm -rf $OUT/r
