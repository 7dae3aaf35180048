"""The simulated world (and the real one's recordings): what the camera looks at and what it delivers.

- ``objects``: object sets: model types, mesh processing, the built-in procedural families, folder and
  BOP loaders;
- ``scenes``: cluttered tables: sampling, the MuJoCo model, JSON;
- ``render``: depth and object ids on three backends; the Kinect-v1 sensor model;
- ``setup``: one world set-up (``WorldConfig`` -> ``make_world`` -> ``World``);
- ``dataset``: scenes x viewpoints on disk, resumable; ``recording``: a real sensor's recorded sequence;
  ``bop``: a dataset's scenes in the BOP benchmark's layout, written and read back.

The world never imports perception, training, the episode or the commands.
"""

import importlib

__all__ = ["World", "WorldConfig", "bop", "dataset", "make_world", "objects", "recording", "render", "scenes", "setup"]


def __getattr__(name: str):
    if name in ("World", "WorldConfig", "make_world"):
        return getattr(importlib.import_module("jaxcls.world.setup"), name)
    if name in __all__:
        return importlib.import_module(f"jaxcls.world.{name}")
    raise AttributeError(f"module 'jaxcls.world' has no attribute {name!r}")
