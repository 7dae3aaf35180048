# Issue 34 on one GPU: the tracking pyramid's paired Table 1 (g10.sh), then a kernel profile of the batched move at
# HEAD (512 episodes, frames in memory), trace and HLO kept.
bash .dev5/s/g10.sh
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.95
mkdir -p $OUT/p
timeout 240 python benchmarks/profile_batched.py --frames $R/.dev5/scene3.npz --batch 512 --keep /tmp/prof --out $OUT/p/prof.md 2>&1 | grep -v Warn | tail -60
cp /tmp/prof/* $OUT/p/ 2>/dev/null; ls -la $OUT/p
