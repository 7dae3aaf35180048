# Round 2, call 2: one GPU warm with XLA_PYTHON_CLIENT_PREALLOCATE=false.
source .dev5/s/pre.sh || exit 1
export XLA_PYTHON_CLIENT_PREALLOCATE=false
LIMIT=580 bash .dev5/s/t1.sh /tmp/g1p oracle_scenes=50
python .dev5/s/cmp.py /tmp/g1 /tmp/g1p | tee $OUT/r/cmp_g1p.txt
cp /tmp/g1p.log $OUT/r/
tar czf $OUT/g1p.tgz -C $OUT r && rm -rf $OUT/r
