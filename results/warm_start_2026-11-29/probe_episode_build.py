import sys, cProfile, pstats
import jax
from jaxcls import compile_cache, precision
from jaxcls.config import load_config
from jaxcls.episode import setup
from jaxcls.experiments.table1 import data, runner
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.world.objects import object_set_from_config
precision.full_float32_matmuls(); compile_cache.enable()
config = load_config(Table1Config, sys.argv[1], sys.argv[2:])
dataset, scene_set = data.open_scenes(config)
object_set = object_set_from_config(dataset.objects)
cl = {n: setup.load_classifier(p, object_set, n) for n, p in config.classifiers.items()}
intr, th, views = scene_set.frame_layout()
row = runner.program_row(runner.protocol.ROWS[config.rows[0]])
pr = cProfile.Profile(); pr.enable()
for c in cl.values():
    runner.episode(config, row, c, object_set, intr, th, dataset.scene.split)
pr.disable()
pstats.Stats(pr).sort_stats("cumulative").print_stats(30)
