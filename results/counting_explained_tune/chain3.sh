while pgrep -f "runs/mm/chain2.sh" > /dev/null; do sleep 5; done
for v in "rl_s8d10 0.8 0.01" "rl_s6d10 0.6 0.01"; do
  set -- $v
  /usr/bin/time -f "$1 wall %e s" python experiments/table1.py --config table1_real_like_estimated 'dataset_overrides=[num_scenes=30,seed=100,out_dir=data/real_like_tune30]' scenes=30 runs=3 'rows=[vis_occl_hist_gr,info_gain_gr]' 'classifiers={shipped: ""}' oracle_scenes=0 out_dir=runs/mm/$1 perception.segmentation.explained_share=$2 perception.segmentation.explained_distance=$3 > runs/mm/$1.log 2>&1
done
