# Session 4: --local-processes 4 again (warm), faulthandler on (a crash prints every thread's stack): /tmp/$D.
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
export PYTHONFAULTHANDLER=1
D=${D:-l4b}
rm -rf /tmp/$D
CACHE=/tmp/cache_s LIMIT=${LIMIT:-280} bash $R/.dev5/s/tl.sh table1_real_like_scale 4 /tmp/$D \
  scene_chunk=50 oracle_scenes=${ORC:-50} "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
for i in 0 1 2 3; do tr '\r' '\n' < /tmp/$D/process.$i.log | grep -v "^episodes" > $OUT/r/${D}_process.$i.log; done
tr '\r' '\n' < /tmp/$D.log | grep -v "^episodes" > $OUT/r/$D.log
tar czf $OUT/g2b.tgz -C $OUT r && rm -rf $OUT/r
