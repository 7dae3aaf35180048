# Round 1, call 1: the start-up probes, then the cache filled by a 200-scene run on 4 processes (the full runs' shapes).
source .dev5/s/pre.sh || exit 1
echo "== one process alone"; CUDA_VISIBLE_DEVICES=0 python .dev5/s/probe_start.py 2>&1 | grep "^\["
echo "== again alone"; CUDA_VISIBLE_DEVICES=0 python .dev5/s/probe_start.py 2>&1 | grep "^\["
echo "== four at once"; for i in 0 1 2 3; do CUDA_VISIBLE_DEVICES=$i python .dev5/s/probe_start.py > /tmp/ps.$i 2>&1 & done; wait; cat /tmp/ps.? | grep "^\["
echo "== alone, XLA_PYTHON_CLIENT_PREALLOCATE=false"; XLA_PYTHON_CLIENT_PREALLOCATE=false CUDA_VISIBLE_DEVICES=0 python .dev5/s/probe_start.py 2>&1 | grep "^\["
echo "== alone, XLA_PYTHON_CLIENT_MEM_FRACTION=0.3"; XLA_PYTHON_CLIENT_MEM_FRACTION=0.3 CUDA_VISIBLE_DEVICES=0 python .dev5/s/probe_start.py 2>&1 | grep "^\["
LIMIT=400 bash .dev5/s/tl.sh 4 /tmp/fill scenes=200 oracle_scenes=50
tar czf $OUT/fill.tgz -C $OUT r && rm -rf $OUT/r
