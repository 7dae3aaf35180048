# Call P3: the oracle split by calls (HEAD): one process (A) against two shares (C), and the run time phases.
NOSCENE=1 source .dev4/s/pre.sh
bash .dev4/s/w.sh .dev4/w.3 || exit 1
R=$PWD; cat .dev4/src_new/COMMIT
cp jaxcls/perception/weights/*.msgpack .dev4/src_new/jaxcls/perception/weights/
one() {
  v=$1; n=$2; shift 2
  (cd $R/.dev4/src_$v && export PYTHONPATH=/tmp/site:$PWD JAXCLS_CACHE_DIR=/tmp/cache_$v && \
   /usr/bin/time -f "$v $n: wall %e s" python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/p_$v/$n \
     rows=[oracle_gr] "classifiers={paper: builtin_paper}" scenes=16 oracle_scenes=16 scene_chunk=16 \
     "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]" "$@" > /tmp/p_$v.$n.log 2>&1)
  tail -1 /tmp/p_$v.$n.log; tr '\r' '\n' < /tmp/p_$v.$n.log | grep -E "^run times" | tail -1 | cut -c1-500
}
one new A
one new B
one new C --processes 2 --process-id 0
one new C --processes 2 --process-id 1
python $R/.dev4/s/cmp2.py /tmp/p_new/A /tmp/p_new/C /tmp/p_new/B
