# Round 1, call 2: 4 processes warm, twice.
source .dev5/s/pre.sh || exit 1
for out in /tmp/l4 /tmp/l4b; do LIMIT=280 bash .dev5/s/tl.sh 4 $out oracle_scenes=50; done
cp /tmp/l4.log $OUT/r/; for i in 0 1 2 3; do cp /tmp/l4/process.$i.log $OUT/r/l4_process.$i.log; done
tar czf $OUT/l4.tgz -C $OUT r && rm -rf $OUT/r
