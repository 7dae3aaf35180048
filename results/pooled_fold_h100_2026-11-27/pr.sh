# A named-stage profile of Table 1's program at 512 episodes (the scale settings).
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
timeout ${LIMIT:-400} python benchmarks/profile_batched.py --frames $R/.dev5/scene3.npz --batch ${B:-512} --keep $OUT/r/prof --out $OUT/r/prof.md 2>&1 | grep -v Warning | tail -40
tar czf $OUT/pr.tgz -C $OUT r && rm -rf $OUT/r
