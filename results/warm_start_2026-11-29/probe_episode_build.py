"""Building each classifier's episode (its model library) in a warm process, under cProfile:
``JAXCLS_CACHE_DIR=... python probe_episode_build.py CONFIG [overrides]``."""

import cProfile
import pstats
import sys

from jaxcls import compile_cache, precision
from jaxcls.config import load_config
from jaxcls.episode import setup
from jaxcls.experiments.table1 import data, runner
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.world.objects import object_set_from_config

precision.full_float32_matmuls()
compile_cache.enable()
config = load_config(Table1Config, sys.argv[1], sys.argv[2:])
dataset, scene_set = data.open_scenes(config)
object_set = object_set_from_config(dataset.objects)
classifiers = {n: setup.load_classifier(p, object_set, n) for n, p in config.classifiers.items()}
intrinsics, table_height, views = scene_set.frame_layout()
row = runner.program_row(runner.protocol.ROWS[config.rows[0]])
profile = cProfile.Profile()
profile.enable()
for classifier in classifiers.values():
    runner.episode(config, row, classifier, object_set, intrinsics, table_height, dataset.scene.split)
profile.disable()
pstats.Stats(profile).sort_stats("cumulative").print_stats(30)
