"""Where a 50-scene chunk's frames go on one GPU: the renderer's set-up, the host's draw, the bank's render, the
sensor model; each timed synchronously (block_until_ready), three chunks (the first compiles)."""
import time

import jax
import numpy as np

from jaxcls import devices
from jaxcls.config import load_config
from jaxcls.experiments.table1 import data
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.world import scenes as sc
from jaxcls.world.dataset import scene_key, scene_seeds
from jaxcls.world.render.sensor import measure
from jaxcls.world.setup import make_world

t0 = time.perf_counter()
cfg = load_config(Table1Config, "table1_real_like_scale", ["dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"])
dataset, scenes = data.open_scenes(cfg)
t = time.perf_counter()
scenes.prepare_renderer()
print(f"prepare_renderer {time.perf_counter() - t:.2f} s", flush=True)
for k in range(3):
    idx = list(range(50 * k, 50 * k + 50))
    t = time.perf_counter()
    c = scenes.chunk(idx)
    t1 = time.perf_counter()
    jax.block_until_ready(c.depth)
    print(f"chunk {k} (Scenes.chunk): returned {t1 - t:.2f} s, frames done {time.perf_counter() - t:.2f} s", flush=True)
object_set, bank = data._bank(dataset.objects, dataset.scene, dataset.camera)
seeds = scene_seeds(dataset.seed, dataset.num_scenes)
for k in range(3, 6):
    idx = list(range(50 * k, 50 * k + 50))
    t = time.perf_counter()
    drawn = [sc.sample_scene(object_set, dataset.scene, seeds[i], dataset.objects) for i in idx]
    T_true = np.stack([make_world(dataset.world_config(), scene=s, object_set=object_set).viewpoints for s in drawn])
    t1 = time.perf_counter()
    frames = bank.render(drawn, T_true, "warp", batch=1024)
    jax.block_until_ready(frames.depth)
    t2 = time.perf_counter()
    with jax.default_device(devices.host_cpu()):
        keys = [scene_key(dataset.seed, i) for i in idx]
    t3 = time.perf_counter()
    measured = [measure(keys[n], frames.depth[n], T_true[n], bank.intrinsics, dataset.sensor) for n in range(len(idx))]
    jax.block_until_ready([d for d, _ in measured])
    t4 = time.perf_counter()
    print(f"chunk {k}: draw {t1 - t:.2f} s, bank.render {t2 - t1:.2f} s, keys {t3 - t2:.2f} s, sensor {t4 - t3:.2f} s",
          flush=True)
print(f"total {time.perf_counter() - t0:.1f} s", flush=True)
