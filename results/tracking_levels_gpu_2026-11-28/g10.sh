# Issue 34: the tracking's pyramid, paired Table 1 on one GPU: the scale config on 200 real-like scenes with 2 and 1
# levels (the same scenes, seeds and shapes), then compare.py (pooled F1 per row, paired scene-bootstrap).
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
export PYTHONFAULTHANDLER=1
for lv in 2 1; do
  CACHE=/tmp/cache_lv LIMIT=${LIMIT:-270} bash $R/.dev5/s/t1.sh table1_real_like_scale 1 /tmp/lv$lv scenes=${SCENES:-200} \
    oracle_scenes=0 scene_chunk=50 perception.tracking.levels=$lv "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"
done
python $R/results/tracking_levels_2026-11-27/compare.py /tmp/lv2 /tmp/lv1 $(python -c "
from jaxcls.world.objects import object_set_from_config
from jaxcls.config import load_config
from jaxcls.experiments.table1 import data
from jaxcls.experiments.table1.config import Table1Config
print(len(object_set_from_config(data.dataset_config(load_config(Table1Config, 'table1_real_like_scale', [])).objects).classes))") \
  | tee $OUT/r/compare_levels.txt
tar czf $OUT/g10.tgz -C $OUT r && rm -rf $OUT/r
