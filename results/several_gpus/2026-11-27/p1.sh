# Call P1 (one GPU): the oracle's fixed cost a process and its records over process shares, old (aafd03b) vs new.
# 16 real-like scenes of the scale config, rendered on the device (warp). Per code: A (cold cache, 1 process),
# then the two shares of 2 processes (--processes 2 --process-id 0|1), one after the other; new also B (warm).
NOSCENE=1 source .dev4/s/pre.sh
bash .dev4/s/w.sh .dev4/w.3 || exit 1
R=$PWD
for v in old new; do
  [ -f .dev4/src_$v/jaxcls/perception/weights/pointnet_builtin_paper.msgpack ] || cp jaxcls/perception/weights/*.msgpack .dev4/src_$v/jaxcls/perception/weights/
done
one() {  # one VERSION NAME [args]: a run of the table1_real_like_scale config from .dev4/src_VERSION
  v=$1; n=$2; shift 2
  (cd $R/.dev4/src_$v && export PYTHONPATH=/tmp/site:$PWD JAXCLS_CACHE_DIR=/tmp/cache_$v JAX_LOG_COMPILES=1 && \
   /usr/bin/time -f "$v $n: wall %e s" python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/p_$v/$n \
     rows=[oracle_gr] "classifiers={paper: builtin_paper}" scenes=16 oracle_scenes=16 scene_chunk=16 \
     "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]" "$@" > /tmp/p_$v.$n.log 2>&1)
  tail -1 /tmp/p_$v.$n.log
  tr '\r' '\n' < /tmp/p_$v.$n.log | grep -E "run times" | tail -1 | cut -c1-600
  echo "  compiles > 1 s: $(grep -E 'Finished XLA compilation' /tmp/p_$v.$n.log | awk '{for(i=1;i<=NF;i++) if($i=="in" && $(i+1)>1) print $0}' | sed 's/Finished XLA compilation of //' | cut -c1-60 | sort | uniq -c | tr '\n' ';')"
}
mkdir -p /tmp/p_old /tmp/p_new
for v in old new; do
  one $v A
  [ $v = new ] && one $v B
  one $v C --processes 2 --process-id 0
  one $v C --processes 2 --process-id 1
done
for v in old new; do python $R/.dev4/s/cmp2.py /tmp/p_$v/A /tmp/p_$v/C; done
python $R/.dev4/s/cmp2.py /tmp/p_new/B /tmp/p_new/C
python $R/.dev4/s/cmp2.py /tmp/p_new/A /tmp/p_new/B
for v in old new; do for n in A B C; do [ -d /tmp/p_$v/$n ] && cp /tmp/p_$v/$n/run_times*.json $OUT/ 2>/dev/null; done; done
tar czf $OUT/p1.tgz /tmp/p_old.*.log /tmp/p_new.*.log /tmp/p_*/*/run_times*.json 2>/dev/null; rm -f $OUT/run_times*.json
