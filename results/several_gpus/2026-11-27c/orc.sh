source .dev5/s/pre.sh
source .dev5/s/run.sh
one() { n=$1; shift; CUDA_VISIBLE_DEVICES=0 JAXCLS_CACHE_DIR=/tmp/cache_s timeout 150 python experiments/table1.py --config table1_real_like_scale out_dir=/tmp/q_$n rows=[oracle_gr] scene_chunk=50 oracle_scenes=50 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]" "$@" > /tmp/q_$n.log 2>&1; tr '\r' '\n' < /tmp/q_$n.log | grep -E "^run times" | tail -1 | cut -c1-300; }
one A; one B --processes 4 --process-id 1; one C --processes 4 --process-id 1
python $R/.dev5/s/cmp2.py /tmp/g1 /tmp/q_A /tmp/q_B /tmp/l4 | tee $OUT/r/cmp_q.txt
python $R/.dev5/s/cmp2.py /tmp/q_B /tmp/q_C /tmp/l4 | tee -a $OUT/r/cmp_q.txt
