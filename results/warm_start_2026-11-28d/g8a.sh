# One H200: the cache filled by one cold run (50 real-like scenes in one chunk, both classifiers, no oracle), then
# the warm start with the renderer's modules imported where it first renders (exported, the default now) against
# imported at the start (import_early, as before 5cd8821), 3 rounds each, alternating, every setting's cache a copy.
source .dev5/s/pre.sh || exit 1
set -f
O="scenes=50 oracle_scenes=0 scene_chunk=50 dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
T=$(date +%s)
JAXCLS_CACHE_DIR=/tmp/xla timeout 200 python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/fill $O \
  > $OUT/r/fill.log 2>&1
echo "fill rc $? in $(( $(date +%s) - T )) s"; tr '\r' '\n' < $OUT/r/fill.log | grep -v "Warn\|warn" | tail -3
du -sh /tmp/xla; ls -laS /tmp/xla | head -8
timeout 380 python benchmarks/first_call.py --config table1_real_like_scale --settings exported import_early \
  --rounds 3 --cache-from /tmp/xla --out $OUT/r/first_call.md $O 2>&1 | grep -v "Warn\|warn" | tail -30
tar czf $OUT/g8a.tgz -C $OUT r && rm -rf $OUT/r
