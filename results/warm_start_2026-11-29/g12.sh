# One H200: the program loads with Python tracebacks in the HLO's locations (A: JAX's default, 100 frames), none
# (B: jax_traceback_in_locations_limit=0) or one user frame (C: jax_include_full_tracebacks_in_locations=false).
source .dev5/s/pre.sh || exit 1
O="scenes=50 oracle_scenes=0 scene_chunk=50 dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
envof() { case $1 in A) echo "X=1";; B) echo "JAX_TRACEBACK_IN_LOCATIONS_LIMIT=0";; C) echo "JAX_INCLUDE_FULL_TRACEBACKS_IN_LOCATIONS=false";; esac; }
for S in A B C; do
  s0=$(date +%s.%N)
  env $(envof $S) JAXCLS_CACHE_DIR=/tmp/x$S timeout 250 python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/fill$S $O > $OUT/r/fill$S.log 2>&1
  echo "fill $S rc $? $(python -c "import time;print(round(time.time()-$s0,1))") s"; grep -h "run times" $OUT/r/fill$S.log | tail -1 | cut -c1-400
done
for r in 1 2 3; do for S in A B C; do
  env $(envof $S) JAXCLS_CACHE_DIR=/tmp/x$S timeout 100 python .dev5/s/probe5.py > $OUT/r/p_${S}_$r.txt 2>/dev/null
  echo "probe $S $r: $(grep -E 'classifiers|LOAD' $OUT/r/p_${S}_$r.txt | tr '\n' ' ')"
done; done
tar czf $OUT/g12.tgz -C $OUT r && rm -rf $OUT/r
