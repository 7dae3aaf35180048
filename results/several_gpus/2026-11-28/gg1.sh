# Round 1, call 3: one GPU warm; the records compared.
source .dev5/s/pre.sh || exit 1
LIMIT=580 bash .dev5/s/t1.sh /tmp/g1 oracle_scenes=50
python .dev5/s/cmp.py /tmp/g1 /tmp/l4 /tmp/l4b | tee $OUT/r/cmp.txt
cp /tmp/g1.log $OUT/r/
tar czf $OUT/g1.tgz -C $OUT r && rm -rf $OUT/r
