# Sourced by every call: environment, the CPU-path wheels (once), data link, frames of scene 3 (once).
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 MPLBACKEND=Agg NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1
if [ ! -d /tmp/site/mujoco ]; then
  [ -d .dev4/p ] || { echo "no wheels here and none installed"; exit 1; }
  mkdir -p /tmp/site && python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .dev4/p/*.whl > /tmp/pip1.log 2>&1 || { tail /tmp/pip1.log; exit 1; }
fi
mkdir -p /tmp/data/gpu $OUT/r; [ -e data ] || ln -sfn /tmp/data data
[ -n "$NOSCENE" ] || [ -f data/gpu/scene3.npz ] || python benchmarks/episode_batched.py --save data/gpu/scene3.npz > /tmp/save.log 2>&1 || tail /tmp/save.log
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | head -4
