# Session 6: the first chunk's cost, cold then warm (the compilation cache and Warp's kernel cache).
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
export JAXCLS_CACHE_DIR=/tmp/cache_p
for n in cold warm warm2; do echo "== $n"
CUDA_VISIBLE_DEVICES=0 timeout 90 python $R/.dev5/s/probe2.py 2>&1 | grep -v "^Module\|^   \|^Warp\|Warning\|warn" | tail -16
done
