# The cache filled by a 200-scene run on 4 processes (the full runs' shapes).
source .dev5/s/pre.sh || exit 1
LIMIT=400 bash .dev5/s/tl.sh 4 /tmp/fill scenes=200 oracle_scenes=50
tar czf $OUT/fill.tgz -C $OUT r && rm -rf $OUT/r
