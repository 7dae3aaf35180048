#!/usr/bin/env bash
# Here: tar .wheels/all and cut it into .dev5/k/N/part (36 MiB each), so that each part plus the tree stays < 64 MiB.
set -e
rm -rf .dev5/k && mkdir -p .dev5/k
tar -cf /tmp/whl.tar -C .wheels/all .
sha256sum /tmp/whl.tar | cut -d' ' -f1 > .dev5/s/whl.sha
split -b $((36 * 1024 * 1024)) -d -a 1 /tmp/whl.tar /tmp/whlpart.
i=1; for f in /tmp/whlpart.*; do mkdir -p .dev5/k/$i; mv $f .dev5/k/$i/part; i=$((i + 1)); done
echo $((i - 1)) > .dev5/s/nparts; ls -la .dev5/k/*
