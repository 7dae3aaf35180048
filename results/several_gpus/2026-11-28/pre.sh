# Sourced by every work call: environment (wheels installed by stage.sh/cv.sh into /tmp/site), data folder.
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 MPLBACKEND=Agg NCCL_NVLS_ENABLE=0
python -c "import mujoco, trimesh, omegaconf, warp, mujoco_warp" 2>/dev/null || { echo "wheels missing"; exit 1; }
mkdir -p /tmp/data $OUT/r
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | head -4
git log --oneline -1 2>/dev/null || true
