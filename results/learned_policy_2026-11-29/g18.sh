# One H200 (stage first): the learned view policy trained (imitation, DAgger) for table1_real_like_scale and
# table1_synthetic_scale (shipped classifier), S training scenes; resumable in /tmp/p_<set> on a warm machine.
source .dev5/s/pre.sh || exit 1
unset PYTHONDONTWRITEBYTECODE; export PYTHONPYCACHEPREFIX=/tmp/pyc JAXCLS_CACHE_DIR=/tmp/xla
set -f
S=${S:-128}; SETS=${SETS:-real_like synthetic}; EXTRA=${EXTRA:-}
for set in $SETS; do
  timeout ${T:-280} python -m jaxcls.cli train-policy --config policy_$set out_dir=/tmp/p_$set train_scenes=$S $EXTRA > $OUT/r/train_$set.log 2>&1; echo "$set rc $?"
  tr '\r' '\n' < $OUT/r/train_$set.log | grep -v "it/s]\|chunk/s]\|round/s]\|update/s]" | tail -6
  mkdir -p $OUT/r/$set; cp /tmp/p_$set/policy.msgpack /tmp/p_$set/policy.json /tmp/p_$set/metrics.json /tmp/p_$set/curve.png /tmp/p_$set/config.yaml $OUT/r/$set/ 2>/dev/null
  python -c "import json; [print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in h.items()}) for h in json.load(open('/tmp/p_$set/metrics.json'))['history']]" 2>&1 | tail -12
done
nvidia-smi --query-gpu=memory.used --format=csv,noheader
tar czf $OUT/g18.tgz -C $OUT r && rm -rf $OUT/r
