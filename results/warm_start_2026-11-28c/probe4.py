"""A warm Table 1 process's start-up steps one after another on the main thread, as ``experiments/table1.py``
sets them up (full-precision float32 products, the compilation cache on): where the seconds before the first
batched call go, with cProfile over the first chunk's frames and the programs' loads.
``python -X importtime probe4.py [scenes]``."""

import time

T0 = time.perf_counter()  # (before the imports below on purpose: their time is what this probe measures)

import cProfile  # noqa: E402
import pstats  # noqa: E402
import sys  # noqa: E402


def t(msg: str) -> None:
    print(f"{time.perf_counter() - T0:6.2f} {msg}", flush=True)


import jax  # noqa: E402

t("import jax")
from jaxcls import compile_cache, precision  # noqa: E402
from jaxcls.config import load_config  # noqa: E402
from jaxcls.episode import setup  # noqa: E402
from jaxcls.experiments.table1 import data, runner  # noqa: E402
from jaxcls.experiments.table1.config import Table1Config  # noqa: E402
from jaxcls.world.objects import object_set_from_config  # noqa: E402

t("imports")
precision.full_float32_matmuls()
compile_cache.enable()
scenes = int(sys.argv[1]) if len(sys.argv) > 1 else 50
config = load_config(Table1Config, "table1_real_like_scale",
                     [f"scenes={2 * scenes}", "oracle_scenes=0", f"scene_chunk={scenes}",
                      "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"])
dataset, scene_set = data.open_scenes(config)
t("config, open_scenes")
jax.devices()
t("devices")
object_set = object_set_from_config(dataset.objects)
t("object set")
classifiers = {}
for name, path in config.classifiers.items():
    classifiers[name] = setup.load_classifier(path, object_set, name)
    t(f"classifier {name}")
scene_set.prepare_renderer()
t("prepare_renderer")
profile = cProfile.Profile()
profile.enable()
chunk = scene_set.chunk(list(range(scenes)))
jax.block_until_ready(chunk.depth)
profile.disable()
t(f"chunk of {scenes} (the first)")
chunk = scene_set.chunk(list(range(scenes, 2 * scenes)))
jax.block_until_ready(chunk.depth)
t(f"chunk of {scenes} (the second)")
todo = [k for k in runner.episode_keys(config, scene_set.count) if runner.protocol.ROWS[k[1]].kind in runner.BATCHED]
loads = cProfile.Profile()
loads.enable()
for name in classifiers:
    runner.compile_cache.ahead = lambda load, what: load()
    runner.load_batched_ahead(config, scene_set, dataset, {name: classifiers[name]}, object_set, todo, 2 * scenes)
    t(f"programs of {name} loaded")
loads.disable()
print("== the first chunk, cumulative")
pstats.Stats(profile).sort_stats("cumulative").print_stats(35)
print("== the first chunk, own time")
pstats.Stats(profile).sort_stats("tottime").print_stats(20)
print("== the programs' loads, cumulative")
pstats.Stats(loads).sort_stats("cumulative").print_stats(30)
