# One H200: first_call.py, one source frame per operation (now) against whole tracebacks (JAX's default), 2 rounds.
source .dev5/s/pre.sh || exit 1
timeout 420 python benchmarks/first_call.py --config table1_real_like_scale --settings exported full_tracebacks --rounds 2 \
  --out $OUT/r/first_call_h200.md scenes=50 oracle_scenes=0 scene_chunk=50 'dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]' \
  > $OUT/r/log.txt 2>&1; echo "rc $?"; tail -40 $OUT/r/log.txt
tar czf $OUT/g13.tgz -C $OUT r && rm -rf $OUT/r
