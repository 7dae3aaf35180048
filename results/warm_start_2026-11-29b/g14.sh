# One H200 (stage first): the warm start with this session's host-side changes, A/B on one filled cache:
# now (exported) against every classifier before the first call (classifiers_first) and the object set made (objects_built).
source .dev5/s/pre.sh || exit 1
set -f
O="scenes=50 oracle_scenes=0 scene_chunk=50 dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
JAXCLS_CACHE_DIR=/tmp/xla timeout 200 python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/fill $O > $OUT/r/fill.log 2>&1; echo "fill rc $?"
timeout 380 python benchmarks/first_call.py --config table1_real_like_scale --settings exported classifiers_first objects_built \
  --rounds 3 --cache-from /tmp/xla --out $OUT/r/first_call_h200.md $O > $OUT/r/log.txt 2>&1; echo "rc $?"; tail -30 $OUT/r/log.txt
tar czf $OUT/g14.tgz -C $OUT r && rm -rf $OUT/r
