# Session 5: stress (renders of the bank, static = JAX graph mode, beside a compiling thread) and the chunk probe.
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
export PYTHONFAULTHANDLER=1 JAXCLS_CACHE_DIR=off
for n in 1 2 3; do
CUDA_VISIBLE_DEVICES=0 timeout 70 python $R/.dev5/s/stress.py free ${SECS:-30} > /tmp/st_free.log 2>&1; echo "free $n: exit $?"
grep -v "^Module\|^   \|^Warp" /tmp/st_free.log | tail -3
done
CUDA_VISIBLE_DEVICES=0 timeout 60 python $R/.dev5/s/probe.py 2>&1 | grep -v "^Module\|^   \|^Warp\|Warning\|warn" | tail -12
