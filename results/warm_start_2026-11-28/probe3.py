"""A warm process's start-up steps one after another on the main thread (as it ran, laid out since to the
project's lint: the same statements): ``python -X importtime probe3.py``."""

import time

T0 = time.perf_counter()  # (before the imports below on purpose: their time is what this probe measures)

import cProfile  # noqa: E402
import pstats  # noqa: E402


def t(msg: str) -> None:
    print(f"{time.perf_counter() - T0:6.2f} {msg}", flush=True)


import jax  # noqa: E402

t("import jax")
from jaxcls.config import load_config  # noqa: E402
from jaxcls.episode import setup  # noqa: E402
from jaxcls.experiments.table1 import data  # noqa: E402
from jaxcls.experiments.table1.config import Table1Config  # noqa: E402
from jaxcls.world.objects import object_set_from_config  # noqa: E402

t("imports")
config = load_config(Table1Config, "table1_real_like_scale",
                     ["scenes=50", "oracle_scenes=0", "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"])
dataset, scene_set = data.open_scenes(config)
t("config, open_scenes")
jax.devices()
t("devices")
object_set = object_set_from_config(dataset.objects)
t("object set")
profile = cProfile.Profile()
profile.enable()
for name, path in config.classifiers.items():
    setup.load_classifier(path, object_set, name)
    t(f"classifier {name}")
profile.disable()
scene_set.prepare_renderer()
t("prepare_renderer")
chunk = scene_set.chunk(list(range(50)))
jax.block_until_ready(chunk.depth)
t("chunk 50")
pstats.Stats(profile).sort_stats("cumulative").print_stats(25)
