#!/usr/bin/env bash
# A/B on the 2-core CPU: Table 1's warm start with the compilation cache writing programs that compile in >= 0.1 s
# only (A, the old default) or every program (B, min_compile_seconds = 0). first_call.py's 2-scene synthetic config
# (small.yaml); each setting's cache filled by one run, then alternating fresh processes A, B, A, B, ...
# Usage (from the repository root): bash results/warm_start_2026-11-28b/ab_min_compile.sh ROUNDS
set -e
W=/tmp/ab_min; rm -rf $W; mkdir -p $W
python -c "
import sys; sys.path.insert(0, 'benchmarks'); import first_call
open('$W/small.yaml', 'w').write(first_call.SMALL.format(classifiers='{shipped: \"\"}', data='$W/data'))"
cat > $W/child.py <<'PY'
import runpy
import sys

import jaxcls.compile_cache as c

c.enable.__defaults__ = (None, float(sys.argv[1]))  # (the setting under test, as experiments/table1.py's enable() gets it)
sys.argv = ["experiments/table1.py", *sys.argv[2:]]
runpy.run_path("experiments/table1.py", run_name="__main__")
PY
for m in 0.1 0; do JAXCLS_CACHE_DIR=$W/c$m python $W/child.py $m --config $W/small.yaml out_dir=$W/fill$m > /dev/null 2>&1; done
for r in $(seq 1 ${1:-5}); do for m in 0.1 0; do
  JAXCLS_CACHE_DIR=$W/c$m python $W/child.py $m --config $W/small.yaml out_dir=$W/o$m.$r > /dev/null 2>&1
  python -c "
import json; d = json.load(open('$W/o$m.$r/run_times.json'))[-1]; m = d['marks_s']
print('min_compile_seconds $m round $r: run %.1f s; classifiers loaded %.1f, programs loaded %.1f, first call dispatched %.1f'
      % (d['total_s'], m['classifiers loaded'], m['batched programs loaded'], m['first batched call dispatched']))"
done; done
