# Issue 35: the count at 1,000 synthetic scenes x 10 runs with every GR policy row, N estimated (scale config).
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
export JAXCLS_CACHE_DIR=/tmp/cache_c
/usr/bin/time -f "wall %e s" timeout ${LIMIT:-540} python experiments/table1.py --config table1_synthetic_scale \
    out_dir=/tmp/cnt2/estimated oracle_scenes=0 'classifiers={shipped: ""}' \
    'rows=[random_gr,vis_no_occl_gr,vis_occl_gr,vis_occl_hist_gr,vis_occl_hist_unc_gr,info_gain_gr,continuous_gr]' \
    perception.shapes.num_objects=estimated perception.shapes.num_segments=8 > /tmp/cnt2.log 2>&1
tr '\r' '\n' < /tmp/cnt2.log | grep -E "run times|wall|Error|Traceback" | tail -4
cp /tmp/cnt2/estimated/table.md $OUT/r/table_estimated.md; cp /tmp/cnt2/estimated/config.yaml $OUT/r/config_estimated.yaml
cp /tmp/cnt2/estimated/run_times.json $OUT/r/rt_estimated.json
XZ_OPT=-T0 tar cJf $OUT/r/cnt2_episodes.tar.xz -C /tmp cnt2/estimated/episodes.jsonl; ls -la $OUT/r
