# Issue 35: the count at 1,000 synthetic scenes x 10 runs, N estimated with GR's explained-parts rule (dbd802e).
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
export JAXCLS_CACHE_DIR=/tmp/cache_c
/usr/bin/time -f "wall %e s" timeout ${LIMIT:-380} python experiments/table1.py --config table1_synthetic_scale \
    out_dir=/tmp/cnt3/estimated oracle_scenes=0 'classifiers={shipped: ""}' \
    'rows=[random_gr,vis_occl_hist_gr,info_gain_gr,continuous_gr]' perception.segmentation.explained_share=0.8 \
    perception.shapes.num_objects=estimated perception.shapes.num_segments=8 > /tmp/cnt3.log 2>&1
tr '\r' '\n' < /tmp/cnt3.log | grep -E "run times|wall|Error|Traceback|episodes:" | tail -3
cp /tmp/cnt3/estimated/table.md $OUT/r/table_estimated.md; cp /tmp/cnt3/estimated/config.yaml $OUT/r/config_estimated.yaml
cp /tmp/cnt3/estimated/run_times.json $OUT/r/rt_estimated.json; cp /tmp/cnt3.log $OUT/r/
XZ_OPT=-T0 tar cJf $OUT/r/cnt3_episodes.tar.xz -C /tmp cnt3/estimated; ls -la $OUT/r
