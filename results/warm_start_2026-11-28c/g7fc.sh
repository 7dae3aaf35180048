# One GPU of the machine: the warm start, the first call waiting for its own classifier's programs (exported, the
# default now) against waiting for every classifier's (wait_all, as before), 3 warm rounds each, alternating.
source .dev5/s/pre.sh || exit 1
CUDA_VISIBLE_DEVICES=0 timeout 580 python benchmarks/first_call.py --config table1_real_like_scale \
  --settings exported wait_all --rounds 3 --out $OUT/r/first_call.md \
  scenes=50 oracle_scenes=0 scene_chunk=50 'dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]' 2>&1 \
  | grep -v "Warn\|warn" | tail -30
tar czf $OUT/fc.tgz -C $OUT r && rm -rf $OUT/r
