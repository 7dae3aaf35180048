# One H200 (stage first): (1) the device chunk in fewer programs (ddaeb91) against the code before it (84d81ec):
# each fills its own cache, records compared; then warm runs interleaved, 3 rounds: old, new, and new on the
# machine as lent (no bytecode written; site-packages ship none). The bytecode of the other runs: /tmp/pyc.
source .dev5/s/pre.sh || exit 1
unset PYTHONDONTWRITEBYTECODE; export PYTHONPYCACHEPREFIX=/tmp/pyc
set -f
mkdir -p /tmp/old && git archive 84d81ec | tar -x -C /tmp/old && echo "old tree $(ls /tmp/old | wc -l) entries"
O="scenes=50 oracle_scenes=0 scene_chunk=50 dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
C="--config table1_real_like_scale"
run() {  # run TREE CACHE OUT [env...]
  local tree=$1 cache=$2 out=$3; shift 3
  (cd $tree && env "$@" PYTHONPATH=/tmp/site:$tree JAXCLS_CACHE_DIR=$cache timeout 200 python experiments/table1.py $C out_dir=$out $O > $out.log 2>&1); echo "$out rc $?"
  python -c "import json; d=json.load(open('$out/run_times.json'))[-1]; print('$out', d['marks_s'], d['phases_s'].get('start-up (Python, imports, config)'))"
}
run /tmp/old /tmp/o/xla /tmp/fo
run $PWD /tmp/n/xla /tmp/fn
python .dev5/s/cmp.py /tmp/fo /tmp/fn
for r in 0 1 2; do
  run /tmp/old /tmp/o/xla /tmp/wo$r
  run $PWD /tmp/n/xla /tmp/wn$r
  run $PWD /tmp/n/xla /tmp/wl$r -u PYTHONPYCACHEPREFIX PYTHONDONTWRITEBYTECODE=1
done
python .dev5/s/cmp.py /tmp/fo /tmp/wo0 /tmp/wn0 /tmp/wl0 /tmp/wn2
mkdir -p $OUT/r && for d in /tmp/fo /tmp/fn /tmp/wo* /tmp/wn* /tmp/wl*; do cp $d/run_times.json $OUT/r/$(basename $d)_times.json; cp $d.log $OUT/r/; done
tar czf $OUT/g17.tgz -C $OUT r && rm -rf $OUT/r
