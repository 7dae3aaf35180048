#!/usr/bin/env bash
set -o pipefail
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
python benchmarks/profile_batched.py --frames .dev5/scene3.npz --batch 512 --keep $OUT/prof --out $OUT/prof.md 2>&1 | grep -v Warning | tail -60
cd $OUT && tar -cJf prof.tar.xz prof && rm -rf prof
