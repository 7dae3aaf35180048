# Session 4: stress.py (a program load beside MuJoCo Warp's renders) in separate processes, faulthandler on.
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
export PYTHONFAULTHANDLER=1 JAXCLS_CACHE_DIR=off
for m in ${MODES:-free free nowarp locked}; do
  timeout 120 python $R/.dev5/s/stress.py $m ${SECS:-30} > /tmp/st_$m.log 2>&1; echo "$m: exit $?"
  grep -v "^Module\|^   \|^Warp" /tmp/st_$m.log | tail -${TAILN:-6}
done
