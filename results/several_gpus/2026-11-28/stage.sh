#!/usr/bin/env bash
# Usage: bash .dev5/s/stage.sh N   (copies .dev5/pN/part into /tmp/stage); after the last, installs.
set -e
mkdir -p /tmp/stage; cp .dev5/p$1/part /tmp/stage/part.$(( $1 - 1 )); echo "staged $1"; ls /tmp/stage
if [ "$(ls /tmp/stage | wc -l)" = 4 ]; then
  cat /tmp/stage/part.0 /tmp/stage/part.1 /tmp/stage/part.2 /tmp/stage/part.3 > /tmp/whl.tar
  echo "$(cat .dev5/s/whl.sha)  /tmp/whl.tar" | sha256sum -c
  mkdir -p /tmp/whl && tar -xf /tmp/whl.tar -C /tmp/whl
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site /tmp/whl/*.whl
  PYTHONPATH=/tmp/site python3 -c "import mujoco, mujoco.mjx, trimesh, omegaconf, jaxlie; print('wheels ok', mujoco.__version__)"
fi
