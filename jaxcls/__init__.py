"""jaxcls: active 3D classification of multiple objects in cluttered scenes, in pure-functional JAX.

The modules follow the pipeline (``../shared/DESIGN.md``): ``assets`` (object sets) -> ``scenes``
(cluttered tables as MuJoCo models) -> ``render`` (depth and object ids; sensor model) -> ``dataset`` /
``recording`` (frames on disk) -> ``tsdf`` (fusion, surface extraction) -> ``segment`` (foreground, N
segments) -> ``pointnet`` (class scores, top-k; trained by ``train`` on ``clouds``). ``geometry`` holds
cameras, poses and viewpoints; ``config`` the YAML configs; ``cli`` the ``jaxcls`` command.

Submodules load on first use (``jaxcls.tsdf``), so that training a classifier does not need MuJoCo.
"""

import importlib

__version__ = "0.1.0"

__all__ = ["assets", "clouds", "config", "dataset", "geometry", "pointnet", "recording", "render", "scenes",
           "segment", "train", "tsdf"]


def __getattr__(name: str):
    if name in __all__:
        return importlib.import_module(f"jaxcls.{name}")
    raise AttributeError(f"module 'jaxcls' has no attribute {name!r}")
