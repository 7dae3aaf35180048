# One H200 (the cache filled first: /tmp/xla, the exported programs beside it): the warm start as it is (exported)
# against JAX's runtime started on a thread at the process's start (devices_thread) and without a preallocated
# pool (no_prealloc); 3 rounds each, alternating, every setting's cache and exported programs a copy of the fill's.
source .dev5/s/pre.sh || exit 1
set -f
O="scenes=50 oracle_scenes=0 scene_chunk=50 dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
if [ ! -d /tmp/xla ]; then
  T=$(date +%s)
  JAXCLS_CACHE_DIR=/tmp/xla timeout 200 python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/fill $O \
    > $OUT/r/fill.log 2>&1
  echo "fill rc $? in $(( $(date +%s) - T )) s"
fi
ls /tmp; ls /tmp/xla | head -3
timeout 440 python benchmarks/first_call.py --config table1_real_like_scale --settings exported devices_thread no_prealloc \
  --rounds 3 --cache-from /tmp/xla --out $OUT/r/first_call.md $O 2>&1 | grep -v "Warn\|warn" | tail -40
ls $OUT/r
tar czf $OUT/g8c.tgz -C $OUT r && rm -rf $OUT/r
