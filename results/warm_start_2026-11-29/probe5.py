"""A warm process loading one classifier's batched program on the main thread, each step timed (for py-spy and
XLA's logs): python probe5.py [scenes]"""
import time

T0 = time.perf_counter()
import sys  # noqa: E402


def t(msg):
    print(f"{time.perf_counter() - T0:6.2f} {msg}", flush=True)
    print(f"PROBE-MARK {msg}", file=sys.stderr, flush=True)


import jax  # noqa: E402

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
                     [f"scenes={scenes}", "oracle_scenes=0", f"scene_chunk={scenes}",
                      "dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"])
dataset, scene_set = data.open_scenes(config)
jax.devices()
t("devices")
object_set = object_set_from_config(dataset.objects)
classifiers = {name: setup.load_classifier(path, object_set, name) for name, path in config.classifiers.items()}
t("classifiers")
todo = [k for k in runner.episode_keys(config, scene_set.count) if runner.protocol.ROWS[k[1]].kind in runner.BATCHED]
runner.compile_cache.ahead = lambda load, what: load()
for name in classifiers:
    t(f"LOAD-START {name}")
    runner.load_batched_ahead(config, scene_set, dataset, {name: classifiers[name]}, object_set, todo, scenes)
    t(f"LOAD-END {name}")
