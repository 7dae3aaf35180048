#!/usr/bin/env bash
# One H200: a cold fill of the cache (the probe's shapes: 100 scenes in chunks of 50, both classifiers, no oracle),
# then the start-up probe twice in fresh warm processes.
source .dev5/s/pre.sh
T=$(date +%s)
timeout 300 python experiments/table1.py --config table1_real_like_scale scenes=100 oracle_scenes=0 scene_chunk=50 \
  timing_moves=0 out_dir=/tmp/fill 'dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]' > $OUT/r/fill.log 2>&1
echo "fill rc $? in $(( $(date +%s) - T )) s"; tail -3 $OUT/r/fill.log
for i in 1 2; do
  python -X importtime .dev5/s/probe4.py 50 > $OUT/r/probe4_$i.txt 2> $OUT/r/imp_$i.txt
  grep -v Warn $OUT/r/probe4_$i.txt | head -16
done
sort -t'|' -k2 -n -r $OUT/r/imp_2.txt | head -30 > $OUT/r/imp_top.txt
tar -czf $OUT/r.tgz -C $OUT r && rm -rf $OUT/r
