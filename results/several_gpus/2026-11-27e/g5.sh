# Session 5: the scale config at HEAD on 4 processes cold (fills /tmp/cache_s: both classifiers), then warm.
NOSCENE=1 source .dev5/s/pre.sh
export PYTHONFAULTHANDLER=1
source .dev5/s/run.sh
for out in /tmp/l4c /tmp/l4; do
  CACHE=/tmp/cache_s LIMIT=280 bash $R/.dev5/s/tl.sh table1_real_like_scale 4 $out \
    scene_chunk=50 oracle_scenes=50 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
done
python $R/.dev5/s/cmp2.py /tmp/l4c /tmp/l4 | tee $OUT/r/cmp_l4c_l4.txt
cp /tmp/l4.log $OUT/r/ 2>/dev/null; for i in 0 1 2 3; do cp /tmp/l4/process.$i.log $OUT/r/l4_process.$i.log; done
tar czf $OUT/g5.tgz -C $OUT r && rm -rf $OUT/r
