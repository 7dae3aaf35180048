# Call M1 (4 GPUs): the last warp part; the shared cache (/tmp/cache_s) filled by a 50-scene run of the scale config
# (the 1,000-scene runs' shapes: chunks of 50 scenes, calls of 500 episodes; the oracle on 2 scenes).
source .dev4/s/pre.sh
bash .dev4/s/w.sh .dev4/w.3 || exit 1
CACHE=/tmp/cache_s LIMIT=500 bash .dev4/s/t1.sh table1_real_like_scale 1 /tmp/warm "classifiers={paper: builtin_paper}" \
  scene_chunk=50 scenes=50 oracle_scenes=2 "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
cat /tmp/warm/run_times.json; du -sh /tmp/cache_s /tmp/exported /tmp/host 2>&1
grep -c oracle /tmp/warm/episodes.jsonl
tr '\r' '\n' < /tmp/warm.log | grep -E "oracle" | tail -3
