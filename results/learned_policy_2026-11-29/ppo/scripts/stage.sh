#!/usr/bin/env bash
# There: bash .dev5/s/stage.sh N [M ...] copies .dev5/k/N/part into /tmp/stage; once all are there, installs.
set -e
mkdir -p /tmp/stage
for n in "$@"; do cp .dev5/k/$n/part /tmp/stage/part.$n; echo "staged $n"; done
if [ "$(ls /tmp/stage | wc -l)" = "$(cat .dev5/s/nparts)" ]; then
  cat $(ls /tmp/stage/part.* | sort -t. -k2 -n) > /tmp/whl.tar
  echo "$(cat .dev5/s/whl.sha)  /tmp/whl.tar" | sha256sum -c
  mkdir -p /tmp/whl && tar -xf /tmp/whl.tar -C /tmp/whl
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site /tmp/whl/*.whl
  PYTHONPATH=/tmp/site python3 -c "import mujoco, mujoco.mjx, mujoco_warp, trimesh, omegaconf, jaxlie, tensorboardX; print('wheels ok', mujoco.__version__)"
fi
