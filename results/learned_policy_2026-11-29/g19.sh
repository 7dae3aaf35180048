# One H200 (stage first): Table 1 at scale with the learned row. g19.sh SET WEIGHTS NAME [overrides...]
# (SET: real_like|synthetic; WEIGHTS: a policy.msgpack in the tree, e.g. .dev5/w/r/real_like/policy.msgpack)
source .dev5/s/pre.sh || exit 1
unset PYTHONDONTWRITEBYTECODE; export PYTHONPYCACHEPREFIX=/tmp/pyc JAXCLS_CACHE_DIR=/tmp/xla
set -f
set=$1; w=$2; name=$3; shift 3
out=/tmp/t1_$name
/usr/bin/time -f "table1 $name: wall %e s" timeout ${LIMIT:-560} python experiments/table1.py --config table1_${set}_scale \
  out_dir=$out scene_chunk=50 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/$set]" nbv.learned.weights=$PWD/$w "$@" > $OUT/r/$name.log 2>&1
tr '\r' '\n' < $OUT/r/$name.log | grep -E "run times|wall|episodes in|Error|error:|Traceback" | tail -6
cp $out/table.md $OUT/r/${name}_table.md 2>/dev/null; cp $out/run_times*.json $OUT/r/ 2>/dev/null
grep -E "^\| (VisOcclHistGR|InfoGainGR|LearnedGR|OracleGR) |^#### |Learned|Oracle against" $out/table.md
cat $out/episodes*.jsonl | xz -T16 -3 > $OUT/r/${name}_episodes.jsonl.xz; ls -la $OUT/r/${name}_episodes.jsonl.xz
tar czf $OUT/$name.tgz -C $OUT r && rm -rf $OUT/r
