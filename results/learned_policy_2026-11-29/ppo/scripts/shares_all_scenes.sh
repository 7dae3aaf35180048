#!/usr/bin/env bash
# shares_all_scenes.md: compare_runs.py for each policy's Table 1 run against the oracle runs (README item 18).
set -e
cd "$(dirname "$0")/../../../.."  # (the repository's root)
R=results/learned_policy_2026-11-29
OUT=$R/ppo/shares_all_scenes.md
rm -f $OUT
{ echo "# Shares of the oracles' leads, with each policy's lead on all the paired scenes"; echo;
  echo "Each section: \`python experiments/compare_runs.py --a <the oracle's run> --b <the policy's run> --out $OUT\`"
  echo "(code after 7fbf876: the last two columns, \`metrics.share_of_gap_all_scenes\`). A = the oracle's run, whose own"
  echo "learned row is the imitation policy (\`real_like_paper\` or \`synthetic_paper\`); B = the policy's run. Then the"
  echo "second draw of held-out real-like scenes (dataset seed 2, \`ppo/seed2/\`), and both draws pooled."; echo; } > $OUT
run() { echo "## B = $(basename $2) against A = $(basename $1)" >> $OUT; echo >> $OUT
  echo "    python experiments/compare_runs.py --a $1/config.yaml --b $2/config.yaml" >> $OUT; echo >> $OUT
  python3 experiments/compare_runs.py --a $1/config.yaml --b $2/config.yaml --out $OUT > /dev/null; echo >> $OUT; }
for b in rollout_labels/table1_real_like_paper_ppo ppo/table1_real_like_paper_ppo300 ppo/table1_real_like_paper_ppo550 \
  ppo/table1_real_like_paper_ppo300_scenes256_250 ppo/table1_real_like_paper_ppo300_window64_250 ppo/table1_real_like_paper_ppo300_window256_240 \
  ppo/table1_real_like_paper_ppo300_group4_250 ppo/table1_real_like_paper_ppo300_scenes256_250_batch2048_100 \
  ppo/table1_real_like_paper_ppo300_scenes256_250_batch2048_180 ppo/table1_real_like_paper_ppo_soup6 ppo/table1_real_like_paper_v3_ppo300 \
  ppo/table1_real_like_paper_v3_ppo300_scenes256_136 ppo/table1_real_like_paper_v3_val96_ppo300 ppo/table1_real_like_paper_v3_val96_ppo300_scenes256_135; do
  for a in rollout_labels/table1_real_like_paper_fair600 rollout_labels/table1_real_like_paper_rollout300; do run $R/$a $R/$b; done
done
for b in ppo/table1_synthetic_paper_ppo250 ppo/table1_synthetic_paper_ppo250_scenes256_115 \
  ppo/table1_synthetic_paper_v3_val96_ppo300 ppo/table1_synthetic_paper_v3_val96_ppo300_scenes256_135; do run $R/ppo/table1_synthetic_paper_oracle $R/$b; done
# The real-like layout-3 policies on the synthetic set against the synthetic PPO policy trained there.
for b in ppo/table1_synthetic_paper_v3_val96_ppo300 ppo/table1_synthetic_paper_v3_val96_ppo300_scenes256_135; do
  run $R/ppo/table1_synthetic_paper_ppo250 $R/$b; done
# The second draw (dataset seed 2): its oracle is in the layout-3 policy's run (A there); then both draws pooled.
S=$R/ppo/seed2
for b in table1_real_like_paper_ppo_scenes256 table1_real_like_paper_v3 table1_real_like_paper_ppo; do
  run $S/table1_real_like_paper_v3_scenes256_oracle400 $S/$b; done
pooled() { echo "## Pooled over both draws: B = $(basename $2) against A = $(basename $1)" >> $OUT; echo >> $OUT
  echo "    python experiments/compare_runs.py --a $1/config.yaml --b $2/config.yaml --a $3/config.yaml --b $4/config.yaml" >> $OUT
  echo >> $OUT; python3 experiments/compare_runs.py --a $1/config.yaml --b $2/config.yaml --a $3/config.yaml \
  --b $4/config.yaml --out $OUT > /dev/null; echo >> $OUT; }
V=$R/ppo/table1_real_like_paper_v3_val96_ppo300_scenes256_135_oracle600
pooled $R/ppo/table1_real_like_paper_ppo300_scenes256_250 $V $S/table1_real_like_paper_ppo_scenes256 $S/table1_real_like_paper_v3_scenes256_oracle400
pooled $R/ppo/table1_real_like_paper_v3_val96_ppo300 $V $S/table1_real_like_paper_v3 $S/table1_real_like_paper_v3_scenes256_oracle400
pooled $R/ppo/table1_real_like_paper_ppo300 $V $S/table1_real_like_paper_ppo $S/table1_real_like_paper_v3_scenes256_oracle400
