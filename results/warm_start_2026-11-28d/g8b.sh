# One H200 (the cache filled by g8a's cold run: /tmp/xla, the exported programs in /tmp/exported; else here): the warm start with
# the renderer's modules imported where it first renders (exported, the default now), imported at the start
# (import_early, as before 5cd8821), and the classifiers' programs loaded one at a time (serial); 3 rounds each,
# alternating, every setting's cache and exported programs a copy of the fill's.
source .dev5/s/pre.sh || exit 1
set -f
O="scenes=50 oracle_scenes=0 scene_chunk=50 dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
if [ ! -d /tmp/exported ]; then
  T=$(date +%s)
  JAXCLS_CACHE_DIR=/tmp/xla timeout 200 python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/fill $O \
    > $OUT/r/fill.log 2>&1
  echo "fill rc $? in $(( $(date +%s) - T )) s"
fi
ls /tmp/exported/*
timeout 480 python benchmarks/first_call.py --config table1_real_like_scale --settings exported import_early serial \
  --rounds 3 --cache-from /tmp/xla --out $OUT/r/first_call.md $O 2>&1 | grep -v "Warn\|warn" | tail -30
tar czf $OUT/g8b.tgz -C $OUT r && rm -rf $OUT/r
