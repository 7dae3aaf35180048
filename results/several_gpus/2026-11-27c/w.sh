# Warp in parts: w.sh PART appends it; the last (LAST env names it) checks the sum and extracts to /tmp/site.
p=$1
[ -d /tmp/site/warp ] && { echo "warp already installed"; exit 0; }
cat $p >> /tmp/w.xz; echo "appended $p: $(stat -c %s /tmp/w.xz)"
if [ "$(basename $p)" = "$LAST" ]; then
  [ "$(sha256sum /tmp/w.xz | cut -c1-64)" = "$(cat .dev5/s/wm.sha)" ] || { echo "warp parts: checksum differs"; exit 1; }
  tar xJf /tmp/w.xz -C /tmp/site && python -c "import warp, mujoco_warp; print('warp', warp.__version__)" 2>&1 | tail -1
fi
