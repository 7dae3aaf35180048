# Session 5: the scene bank's GPU render, static (mocap poses in JAX) vs forward (mjx.forward), against the C caster.
NOSCENE=1 source .dev5/s/pre.sh
source .dev5/s/run.sh
CUDA_VISIBLE_DEVICES=0 timeout ${LIMIT:-300} python benchmarks/scene_bank.py --config real_like --scenes ${S:-10} --batch 1024 \
  --repeats 2 --kinematics static forward --out $OUT/r/bank.md 2>&1 | grep -v -i warning | tail -12
cp $OUT/r/bank.md $OUT/bank.md
