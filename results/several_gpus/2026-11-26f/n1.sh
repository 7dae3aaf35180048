# Call N1: the last warp part; the shared cache filled by a 50-scene one-GPU run (the 1,000-scene runs' shapes).
source .dev4/s/pre.sh
bash .dev4/s/w.sh .dev4/w.3 || exit 1
CACHE=/tmp/cache_s LIMIT=400 bash .dev4/s/t1.sh table1_real_like_scale 1 /tmp/warm "classifiers={paper: builtin_paper}" \
  scene_chunk=50 scenes=50 oracle_scenes=0 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
rm -rf $OUT/r
