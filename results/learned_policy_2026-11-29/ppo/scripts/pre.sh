# There, sourced by a work script: the staged wheels and the tree on PYTHONPATH, $OUT/r for outputs.
[ -d /tmp/site/mujoco ] || { echo "not staged: run .dev5/s/stage.sh first"; return 1; }
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 MPLBACKEND=Agg
mkdir -p $OUT/r
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
