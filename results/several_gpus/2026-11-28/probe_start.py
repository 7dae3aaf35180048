"""A process's start-up steps one after another (seconds since the process started): imports, the renderer's
modules, the devices, the first transfer (the allocator's first allocation). Run alone or as 4 at once."""
import time

T0 = time.perf_counter()

import os  # noqa: E402
import sys  # noqa: E402


def t(msg):
    print(f"[{os.environ.get('CUDA_VISIBLE_DEVICES', '-')}] {time.perf_counter() - T0:6.2f} {msg}", flush=True)


import jax  # noqa: E402

t("import jax")
from jaxcls.experiments.table1 import data, runner  # noqa: E402, F401
from jaxcls.world.objects import object_set_from_config  # noqa: E402, F401

t("imports (table1)")
from jaxcls.world.render import warp  # noqa: E402, F401

t("import the warp renderer (mujoco.mjx, mujoco_warp, warp)")
jax.devices()
t("jax.devices()")
jax.device_put(jax.numpy.zeros(4)).block_until_ready()
t("first transfer")
x = jax.device_put(jax.numpy.zeros((1024, 1024, 256)))
x.block_until_ready()
t("1 GiB allocated")
sys.stdout.flush()
os._exit(0)
