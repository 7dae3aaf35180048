"""Does a program load on another thread crash MuJoCo Warp's renders? stress.py MODE SECONDS
MODE: free (renders on this thread, compiles on another), locked (the same, never at once), nowarp (a plain JAX
program instead of the renders)."""
import sys, threading, time
import jax, jax.numpy as jnp, numpy as np
from jaxcls.config import load_config
from jaxcls.experiments.table1 import data
from jaxcls.experiments.table1.config import Table1Config

mode, seconds = sys.argv[1], float(sys.argv[2])
cfg = load_config(Table1Config, "table1_real_like_scale", ["dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"])
dataset, scenes = data.open_scenes(cfg)
lock = threading.Lock() if mode == "locked" else None
stop, count = False, [0]

def loader():
    i = 0
    while not stop:
        f = jax.jit(lambda x, i=i: jnp.cumsum(jnp.sin(x) * (i + 1.0)) @ jnp.ones((x.shape[0], 64)))
        if lock:
            with lock:
                jax.block_until_ready(f(jnp.ones(4096 + i)))
        else:
            jax.block_until_ready(f(jnp.ones(4096 + i)))
        i += 1
    count[0] = i

if mode == "ahead":  # the code's own guard: loads through compile_cache.ahead, renders lock inside (no_loads)
    from jaxcls import compile_cache
    def loader():
        i = 0
        while not stop:
            f = jax.jit(lambda x, i=i: jnp.cumsum(jnp.sin(x) * (i + 1.0)) @ jnp.ones((x.shape[0], 64)))
            compile_cache.ahead(lambda f=f, i=i: jax.block_until_ready(f(jnp.ones(4096 + i))), "stress").result()
            i += 1
        count[0] = i
x = jnp.ones((4096, 4096))
t = threading.Thread(target=loader)
t.start()
began, k = time.time(), 0
while time.time() - began < seconds:
    if mode == "nowarp":
        jax.block_until_ready(jnp.tanh(x @ x))
    elif lock:
        with lock:
            jax.block_until_ready(scenes.chunk(list(range(k % 100 * 8, k % 100 * 8 + 8))).depth)
    else:
        jax.block_until_ready(scenes.chunk(list(range(k % 100 * 8, k % 100 * 8 + 8))).depth)
    k += 1
stop = True
t.join()
print(f"{mode}: {k} renders, {count[0]} programs compiled and run beside them, no crash", flush=True)
