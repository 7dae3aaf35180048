# Call M3: the same on 4 processes (one a GPU), then 2; records compared with the 1-GPU run.
source .dev4/s/pre.sh
for n in ${NS:-4 2}; do
CACHE=/tmp/cache_s LIMIT=${L2:-400} bash .dev4/s/t1mp.sh table1_real_like_scale $n /tmp/g$n "classifiers={paper: builtin_paper}" \
  scene_chunk=50 oracle_scenes=${ORC:-0} "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]" 2>&1 | grep -v "UNAVAILABLE\|WatchTasks"
done
python .dev4/s/cmp2.py /tmp/g1 $(for n in ${NS:-4 2}; do echo /tmp/g$n; done)
xz -T0 -c /tmp/g1/episodes.jsonl > $OUT/r/g1_episodes.jsonl.xz; ls -la $OUT/r
tar czf $OUT/m3.tgz -C $OUT r && rm -rf $OUT/r
