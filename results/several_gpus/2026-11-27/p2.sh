# Call P2: the same as P1's new runs with kernels=deterministic (float scatters in a fixed order, not atomics).
NOSCENE=1 source .dev4/s/pre.sh
R=$PWD
one() {
  v=$1; n=$2; shift 2
  (cd $R/.dev4/src_$v && export PYTHONPATH=/tmp/site:$PWD JAXCLS_CACHE_DIR=/tmp/cache_$v && \
   /usr/bin/time -f "$v $n: wall %e s" python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/p_$v/$n \
     rows=[oracle_gr] "classifiers={paper: builtin_paper}" scenes=16 oracle_scenes=16 scene_chunk=16 kernels=deterministic \
     "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]" "$@" > /tmp/p_$v.$n.log 2>&1)
  tail -1 /tmp/p_$v.$n.log; tr '\r' '\n' < /tmp/p_$v.$n.log | grep -E "run times" | tail -1 | cut -c1-400
}
one new D
one new E --processes 2 --process-id 0
one new E --processes 2 --process-id 1
python $R/.dev4/s/cmp2.py /tmp/p_new/D /tmp/p_new/E /tmp/p_new/A
