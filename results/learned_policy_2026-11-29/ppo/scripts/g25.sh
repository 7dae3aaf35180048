# One H200 (stage first): jaxcls train-policy --config $CFG $X into /tmp/p_$NAME (resumes on a warm machine),
# limited to T s; tars its files into $OUT/train_$NAME.tgz.
source .dev5/s/pre.sh || exit 1
unset PYTHONDONTWRITEBYTECODE; export PYTHONPYCACHEPREFIX=/tmp/pyc JAXCLS_CACHE_DIR=/tmp/xla
set -f
p=/tmp/p_$NAME; mkdir -p $OUT/r/train_$NAME
/usr/bin/time -f "train $NAME: wall %e s" timeout ${T:-560} python -m jaxcls.cli train-policy --config $CFG out_dir=$p $X \
  > $OUT/r/train_$NAME/train.log 2>&1; echo "train $NAME rc $?"
tr '\r' '\n' < $OUT/r/train_$NAME/train.log | grep -v "it/s]\|chunk/s]\|round/s]\|update/s]\|^ *$" | tail -5
python -c "import json; [print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in h.items()}) for h in json.load(open('$p/metrics.json'))['history']]" 2>&1 | tail -40
cp $p/policy.msgpack $p/policy.json $p/metrics.json $p/curve.png $p/config.yaml $OUT/r/train_$NAME/ 2>/dev/null
tar czf $OUT/train_$NAME.tgz -C $OUT/r train_$NAME && rm -rf $OUT/r/train_$NAME
