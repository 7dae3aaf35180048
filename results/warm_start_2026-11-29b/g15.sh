# One H200 (stage first): which programs a warm run's start traces, lowers and loads, with times (JAX's compile
# log, each line stamped), and a py-spy profile (Python frames, every thread) of another warm run.
source .dev5/s/pre.sh || exit 1
set -f
python3 -m pip install -q --no-index --no-deps --target /tmp/pyspy .dev5/tools/py_spy-0.4.3-py2.py3-none-manylinux1_x86_64.manylinux_2_5_x86_64.whl && export PATH=/tmp/pyspy/bin:$PATH
O="scenes=50 oracle_scenes=0 scene_chunk=50 dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
export JAXCLS_CACHE_DIR=/tmp/xla15
timeout 200 python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/fill15 $O > $OUT/r/fill.log 2>&1; echo "fill rc $?"
timeout 100 python .dev5/s/logrun.py --config table1_real_like_scale out_dir=/tmp/w1 $O > $OUT/r/w1.out 2> $OUT/r/w1.log; echo "w1 rc $?"
python -c "import json; print(json.load(open('/tmp/w1/run_times.json')).get('marks_s'))"
grep -c "Compiling\|Finished" $OUT/r/w1.log
timeout 100 py-spy record --threads -r 50 -f raw -o $OUT/r/w2.raw -- python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/w2 $O > $OUT/r/w2.out 2>&1; echo "w2 rc $?"
python -c "import json; print(json.load(open('/tmp/w2/run_times.json')).get('marks_s'))"
cp /tmp/w1/run_times.json $OUT/r/w1_times.json
tar czf $OUT/g15.tgz -C $OUT r && rm -rf $OUT/r
