#!/usr/bin/env bash
# P=.dev5/v.NN bash .dev5/s/cv.sh : stage one part of MuJoCo Warp (warp-lang without its CPU compiler, examples, tests);
# after the last (v.11), unpack into /tmp/site.
set -e
mkdir -p /tmp/wstage; cp $P/part /tmp/wstage/$(basename $P); echo "staged $P: $(ls /tmp/wstage | wc -l)"
if [ "$(ls /tmp/wstage | wc -l)" = "$(cat .dev5/s/warp.count)" ]; then
  cat /tmp/wstage/v.* > /tmp/warp.tar.xz
  echo "$(cat .dev5/s/warp.sha)  /tmp/warp.tar.xz" | sha256sum -c
  mkdir -p /tmp/site && tar -xJf /tmp/warp.tar.xz -C /tmp/site
  PYTHONPATH=/tmp/site python3 -c "import warp, mujoco_warp; print('warp', warp.__version__)"
fi
