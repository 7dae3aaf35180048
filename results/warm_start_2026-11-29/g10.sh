# One H200 (stage first: bash .dev5/s/stage2.sh 1..7, carry [".dev5/s", ".dev5/k/N"]; this call carries
# [".dev5/s", ".dev5/tools"]): where a warm run's program loads go. Fill the cache (one cold run), then one warm
# run of the same command under py-spy (native frames): is a load's time XLA re-emitting the kernels' LLVM IR
# (the legacy cache entry), the CUDA module loads, or the proto parsing?
source .dev5/s/pre.sh || exit 1
set -f
python3 -m pip install -q --no-index --no-deps --target /tmp/pyspy .dev5/tools/py_spy-0.4.3-py2.py3-none-manylinux1_x86_64.manylinux_2_5_x86_64.whl && export PATH=/tmp/pyspy/bin:$PATH
O="scenes=50 oracle_scenes=0 scene_chunk=50 dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
JAXCLS_CACHE_DIR=/tmp/xla timeout 200 python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/fill $O \
  > $OUT/r/fill.log 2>&1; echo "fill rc $?"
JAXCLS_CACHE_DIR=/tmp/xla timeout 200 py-spy record --native --threads -r 50 -f raw -o $OUT/r/warm.raw -- \
  python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/warm1 $O > $OUT/r/warm.log 2>&1
echo "warm rc $?"; tr '\r' '\n' < $OUT/r/warm.log | grep "run times" | tail -2
grep -o "[A-Za-z_:]*\(LoadExecutable\|Deserialize\|FromProto\|IrEmitter\|ModuleLoad\|cuModuleLoad\|ptx\|Thunk\)[A-Za-z_:]*" $OUT/r/warm.raw | sort | uniq -c | sort -rn | head -20
JAXCLS_CACHE_DIR=/tmp/xla timeout 120 python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/warm2 $O > $OUT/r/warm2.log 2>&1
echo "warm2 rc $?"; cat /tmp/warm2/run_times.json 2>/dev/null | head -40 > $OUT/r/warm2_times.json
for f in $(python3 - <<'PY'
import glob, os, site
roots = [p for p in __import__('sys').path if p.endswith('site-packages') or p.endswith('dist-packages')]
for r in roots:
    for g in glob.glob(r + '/**/*.so', recursive=True):
        if 'xla' in os.path.basename(g) or 'pjrt' in os.path.basename(g) or 'jaxlib' in g and os.path.getsize(g) > 5e7:
            print(g)
PY
); do echo "== $f"; strings -n 12 $f | grep -o 'xla_gpu_[a-z0-9_]*\(thunk\|aot\|serializ\|cache\|load\|executable\)[a-z0-9_]*' | sort -u; done > $OUT/r/flags.txt 2>&1
tar czf $OUT/g10.tgz -C $OUT r && rm -rf $OUT/r
