# Session 6: a warm run's start on one GPU: the first frames made beside the classifiers' load against after it.
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
export PYTHONFAULTHANDLER=1
timeout ${LIMIT:-560} python benchmarks/first_call.py --config table1_real_like_scale --settings exported frames_later \
  --rounds ${ROUNDS:-2} --out $OUT/r/first_call_gpu.md scenes=100 oracle_scenes=0 scene_chunk=50 \
  "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]" 2>&1 | grep -v "Warning\|warn" | tail -14
tar czf $OUT/g9.tgz -C $OUT r && rm -rf $OUT/r
