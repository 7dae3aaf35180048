# Round 2, call 1: 4 processes warm, twice, with XLA_PYTHON_CLIENT_PREALLOCATE=false (no 75% of the GPU taken at the first transfer).
source .dev5/s/pre.sh || exit 1
export XLA_PYTHON_CLIENT_PREALLOCATE=false
for out in /tmp/l4p /tmp/l4pb; do LIMIT=280 bash .dev5/s/tl.sh 4 $out oracle_scenes=50; done
python .dev5/s/cmp.py /tmp/l4 /tmp/l4p /tmp/l4pb | tee $OUT/r/cmp_p.txt
tar czf $OUT/l4p.tgz -C $OUT r && rm -rf $OUT/r
