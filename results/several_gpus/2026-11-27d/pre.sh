# Sourced by every call: environment, the CPU-path wheels (once, from .wheels/p1), data link.
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 MPLBACKEND=Agg NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1
if [ ! -d /tmp/site/mujoco ]; then
  WH=${WH:-.wheels/p1}; [ -d $WH ] || { echo "no wheels here and none installed"; exit 1; }
  mkdir -p /tmp/site && python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site $WH/*.whl > /tmp/pip1.log 2>&1 || { tail /tmp/pip1.log; exit 1; }
  python -c "import mujoco, trimesh, omegaconf; print('cpu wheels ok')"
fi
mkdir -p /tmp/data $OUT/r
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | head -4
