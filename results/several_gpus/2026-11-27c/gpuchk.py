"""Frames of scenes 32-38 rendered in a chunk of scenes 0-49 against a chunk of scenes 6-12 and 32-38 (an oracle
share's), bit for bit: with every render call of 1,024 worlds (the fix) and with a shorter last call (before)."""
import time

import numpy as np

from jaxcls.config import load_config, resolve_config
from jaxcls.experiments.table1 import data
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.world import bank

config = load_config(Table1Config, resolve_config("table1_real_like_scale"),
                     ["dataset_overrides=[num_scenes=1000,out_dir=/tmp/data/rl]"])
dataset, scenes = data.open_scenes(config)
share = [*range(6, 13), *range(32, 39)]
fixed = bank.launches


def before(frames, batch):
    return [np.arange(a, min(a + batch, frames)) for a in range(0, frames, batch)]


for name, plan in (("fixed (every call 1,024 worlds)", fixed), ("before (a shorter last call)", before)):
    bank.launches = plan
    t = time.perf_counter()
    full = np.asarray(scenes.chunk(list(range(50))).depth)
    part = np.asarray(scenes.chunk(share).depth)
    same = [bool(np.array_equal(full[s], part[i])) for i, s in enumerate(share)]
    diff = [int((full[s] != part[i]).sum()) for i, s in enumerate(share)]
    print(f"{name}: scenes {share}: identical {same}; pixels differing {diff} ({time.perf_counter() - t:.1f} s)",
          flush=True)
