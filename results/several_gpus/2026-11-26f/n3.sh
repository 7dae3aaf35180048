# Call N3: the one-GPU run, warm; compared with the --local-processes runs.
source .dev4/s/pre.sh
CACHE=/tmp/cache_s LIMIT=500 bash .dev4/s/t1.sh table1_real_like_scale 1 /tmp/g1 "classifiers={paper: builtin_paper}" \
  scene_chunk=50 oracle_scenes=0 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
python .dev4/s/cmp2.py /tmp/g1 $(ls -d /tmp/l? 2>/dev/null)
tar czf $OUT/n3.tgz -C $OUT r && rm -rf $OUT/r
