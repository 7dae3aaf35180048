while pgrep -f "out_dir=runs/mm/off" > /dev/null; do sleep 5; done
for v in "s8d10 0.8 0.01" "s6d10 0.6 0.01" "s8d05 0.8 0.005"; do
  set -- $v
  /usr/bin/time -f "$1 wall %e s" python experiments/table1.py --config table1_synthetic_estimated 'dataset_overrides=[num_scenes=30,seed=100,out_dir=data/synthetic_tune30]' scenes=30 runs=3 'rows=[vis_occl_hist_gr,info_gain_gr]' 'classifiers={shipped: ""}' oracle_scenes=0 out_dir=runs/mm/$1 perception.segmentation.explained_share=$2 perception.segmentation.explained_distance=$3 > runs/mm/$1.log 2>&1
done
