for f in 0.3 0.5; do
  /usr/bin/time -f "rl50 rho$f wall %e s" python experiments/table1.py --config results/counting_real_like_50_ma5/estimated/config.yaml out_dir=runs/rl50_rho$f perception.segmentation.explained_share=0.8 perception.segmentation.explained_min_rho=$f > runs/rl50_rho$f.log 2>&1
  /usr/bin/time -f "syn rho$f wall %e s" python experiments/table1.py --config table1_synthetic_estimated 'dataset_overrides=[num_scenes=30,seed=100,out_dir=data/synthetic_tune30]' scenes=30 runs=3 'rows=[vis_occl_hist_gr,info_gain_gr]' 'classifiers={shipped: ""}' oracle_scenes=0 out_dir=runs/mm/s8d10r$f perception.segmentation.explained_share=0.8 perception.segmentation.explained_min_rho=$f > runs/mm/s8d10r$f.log 2>&1
done
