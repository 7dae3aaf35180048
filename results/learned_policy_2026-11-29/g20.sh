# One H200 (stage first): the learned policy v2 (features layout 2, started as InfoGain, the set loss) trained for
# table1_real_like_scale (shipped classifier), then Table 1 real_like rows with it (both classifiers), then the
# synthetic set with the real_like weights (generalisation). Each step tars its own output (a kill keeps the rest).
source .dev5/s/pre.sh || exit 1
unset PYTHONDONTWRITEBYTECODE; export PYTHONPYCACHEPREFIX=/tmp/pyc JAXCLS_CACHE_DIR=/tmp/xla
set -f
p=/tmp/p2_real_like
timeout ${T:-230} python -m jaxcls.cli train-policy --config policy_real_like out_dir=$p train_scenes=${S:-128} > $OUT/r/train.log 2>&1; echo "train rc $?"
tr '\r' '\n' < $OUT/r/train.log | grep -v "it/s]\|chunk/s]\|round/s]\|update/s]" | tail -4
python -c "import json; [print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in h.items()}) for h in json.load(open('$p/metrics.json'))['history']]" 2>&1 | tail -8
cp $p/policy.msgpack $p/policy.json $p/metrics.json $p/curve.png $p/config.yaml $OUT/r/ 2>/dev/null
tar czf $OUT/train.tgz -C $OUT r && rm -rf $OUT/r && mkdir -p $OUT/r
t1() {  # name set limit overrides...
  name=$1; set=$2; lim=$3; shift 3; out=/tmp/t1_$name
  /usr/bin/time -f "table1 $name: wall %e s" timeout $lim python experiments/table1.py --config table1_${set}_scale \
    out_dir=$out scene_chunk=50 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/$set]" nbv.learned.weights=$p/policy.msgpack "$@" > $OUT/r/$name.log 2>&1
  tr '\r' '\n' < $OUT/r/$name.log | grep -E "run times|wall|Error|error:|Traceback" | tail -4
  cp $out/table.md $OUT/r/${name}_table.md 2>/dev/null
  grep -E "^\| (VisOcclHistGR|InfoGainGR|LearnedGR|OracleGR) |^#### |Learned" $out/table.md
  xz -T16 -3 -c $out/episodes.jsonl > $OUT/r/${name}_episodes.jsonl.xz; ls -la $OUT/r/${name}_episodes.jsonl.xz
  tar czf $OUT/$name.tgz -C $OUT r && rm -rf $OUT/r && mkdir -p $OUT/r
}
[ -f $p/policy.msgpack ] || exit 1
t1 rl2 real_like ${L1:-230} 'rows=[vis_occl_hist_gr,info_gain_gr,learned_gr]' oracle_scenes=0
t1 gen_syn synthetic ${L2:-110} 'rows=[info_gain_gr,learned_gr]' oracle_scenes=0 'classifiers={shipped: ""}'
