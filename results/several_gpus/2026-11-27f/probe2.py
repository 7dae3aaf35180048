"""Where a process's first chunk of frames goes (the Table 1 run's own set-up: cache on, full float32 matmuls),
each step timed synchronously: imports, scenes opened, the bank, its renderer, the render context, the first and
second bank.render of 50 scenes, the sensor's first and second chunk, then Scenes.chunk twice."""
import time

t0 = time.perf_counter()  # (before the imports: they are timed)
import jax  # noqa: E402
import numpy as np  # noqa: E402

from jaxcls import compile_cache, devices, precision  # noqa: E402
from jaxcls.config import load_config  # noqa: E402
from jaxcls.experiments.table1 import data  # noqa: E402
from jaxcls.experiments.table1.config import Table1Config  # noqa: E402
from jaxcls.world import scenes as sc  # noqa: E402
from jaxcls.world.dataset import scene_key, scene_seeds  # noqa: E402
from jaxcls.world.render.sensor import measure  # noqa: E402
from jaxcls.world.setup import make_world  # noqa: E402


def lap(what, t):
    print(f"{what}: {time.perf_counter() - t:.2f} s", flush=True)
    return time.perf_counter()

t = lap("imports", t0)
precision.full_float32_matmuls()
compile_cache.enable()
cfg = load_config(Table1Config, "table1_real_like_scale", ["dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"])
dataset, scenes = data.open_scenes(cfg)
jax.devices()
t = lap("open_scenes + devices", t)
object_set, bank = data._bank(dataset.objects, dataset.scene, dataset.camera)
t = lap("SceneBank.build", t)
r = bank.warp_renderer()
t = lap("warp_renderer (put_model, make_data)", t)
r._context(1024)
t = lap("render context 1024", t)
seeds = scene_seeds(dataset.seed, dataset.num_scenes)
for k in range(2):
    idx = list(range(50 * k, 50 * k + 50))
    drawn = [sc.sample_scene(object_set, dataset.scene, seeds[i], dataset.objects) for i in idx]
    T_true = np.stack([make_world(dataset.world_config(), scene=s, object_set=object_set).viewpoints for s in drawn])
    t = lap(f"chunk {k}: draw", t)
    frames = bank.render(drawn, T_true, "warp", batch=1024)
    jax.block_until_ready(frames.depth)
    t = lap(f"chunk {k}: bank.render", t)
    with jax.default_device(devices.host_cpu()):
        keys = [scene_key(dataset.seed, i) for i in idx]
    measured = [measure(keys[n], frames.depth[n], T_true[n], bank.intrinsics, dataset.sensor) for n in range(50)]
    jax.block_until_ready([d for d, _ in measured])
    t = lap(f"chunk {k}: keys + sensor", t)
for k in range(2, 4):
    c = scenes.chunk(list(range(50 * k, 50 * k + 50)))
    jax.block_until_ready(c.depth)
    t = lap(f"chunk {k}: Scenes.chunk", t)
print(f"total {time.perf_counter() - t0:.1f} s", flush=True)
