# How the device calls got MuJoCo Warp (run here, in the repository's root; .dev5/ excluded in .git/info/exclude):
# the wheels unpacked without warp-clang (CPU kernels only; warp loads it only where present), warp's tests and
# examples, xz-compressed and cut into parts of 21 MB (the tree is ~43 MB of the 64 MiB a call may carry).
# Each call carries [.dev5/s, .dev5/w.N] (w.sh appends the part; the last checks the sum and unpacks).
set -e
mkdir -p .dev5/wdl .dev5/wsite .dev5/s
plat=(); for n in 17 24 27 28 31 34 35; do plat+=(--platform "manylinux_2_${n}_x86_64"); done
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp "${plat[@]}" \
  --platform manylinux2014_x86_64 -d .dev5/wdl mujoco-warp==4.0.0 warp-lang==1.19.0
(cd .dev5/wsite && unzip -q -o ../wdl/warp_lang-*.whl && unzip -q -o ../wdl/mujoco_warp-*.whl)
rm -rf .dev5/wsite/warp/bin/warp-clang.so .dev5/wsite/warp/tests .dev5/wsite/warp/examples
tar cf - -C .dev5/wsite . | xz -9 -T2 > .dev5/w.xz
(cd .dev5 && split -b 21000000 -d -a 1 w.xz w. && sha256sum w.xz | cut -c1-64 > s/wm.sha)
