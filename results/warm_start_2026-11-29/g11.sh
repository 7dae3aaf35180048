# One H200, warm cache in /tmp/xla from g10: one classifier's program loaded on the main thread: (a) plain, (b) under
# py-spy --native at 10 Hz, (c) with XLA's VLOG 1 (summarised by source).
source .dev5/s/pre.sh || exit 1
python3 -m pip install -q --no-index --no-deps --target /tmp/pyspy .dev5/tools/py_spy-0.4.3-py2.py3-none-manylinux1_x86_64.manylinux_2_5_x86_64.whl && export PATH=/tmp/pyspy/bin:$PATH
export JAXCLS_CACHE_DIR=/tmp/xla
timeout 100 python .dev5/s/probe5.py > $OUT/r/plain.txt 2>$OUT/r/plain.err; echo "plain rc $?"; cat $OUT/r/plain.txt
timeout 100 python .dev5/s/probe5.py > $OUT/r/plain2.txt 2>/dev/null; echo "plain2 rc $?"; cat $OUT/r/plain2.txt
timeout 200 py-spy record --native -r 10 -f raw -o $OUT/r/load.raw -- python .dev5/s/probe5.py > $OUT/r/spy.txt 2>$OUT/r/spy.err
echo "spy rc $?"; cat $OUT/r/spy.txt; tail -3 $OUT/r/spy.err
TF_CPP_MIN_LOG_LEVEL=0 TF_CPP_MAX_VLOG_LEVEL=1 timeout 150 python .dev5/s/probe5.py > $OUT/r/vlog.txt 2>/tmp/vlog.err
echo "vlog rc $?"; cat $OUT/r/vlog.txt; ls -la /tmp/vlog.err
python .dev5/s/vlogsum.py /tmp/vlog.err > $OUT/r/vlogsum.txt; head -60 $OUT/r/vlogsum.txt
grep -c . /tmp/vlog.err; xz -T8 -c /tmp/vlog.err | head -c 15000000 > $OUT/r/vlog.err.xz
tar czf $OUT/g11.tgz -C $OUT r && rm -rf $OUT/r
