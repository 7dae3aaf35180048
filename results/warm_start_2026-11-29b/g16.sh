# One H200 (stage first): the warm start with Python's bytecode written and read (as a pip-installed environment
# has it; this machine's image sets PYTHONDONTWRITEBYTECODE=1 and ships no __pycache__) against every module
# compiled from its source at import (no_bytecode: the machine as lent). The filling run writes the bytecode.
source .dev5/s/pre.sh || exit 1
unset PYTHONDONTWRITEBYTECODE
set -f
O="scenes=50 oracle_scenes=0 scene_chunk=50 dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
JAXCLS_CACHE_DIR=/tmp/xla timeout 200 python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/fill $O > $OUT/r/fill.log 2>&1; echo "fill rc $?"
python -c "import numpy, os; print('numpy pyc', len(os.listdir(os.path.dirname(numpy.__file__) + '/__pycache__')))"
timeout 380 python benchmarks/first_call.py --config table1_real_like_scale --settings exported no_bytecode \
  --rounds 3 --cache-from /tmp/xla --out $OUT/r/first_call_h200.md $O > $OUT/r/log.txt 2>&1; echo "rc $?"; tail -22 $OUT/r/log.txt
tar czf $OUT/g16.tgz -C $OUT r && rm -rf $OUT/r
