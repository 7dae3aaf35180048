"""Depth rendering of static tabletop scenes: MuJoCo C ray casting, MJX ray casting, MJX's Warp renderer.

Conventions (docs/ARCHITECTURE.md): metres; OpenCV cameras given by camera-to-world ``T_wc``; depth is
z-depth, 0 = no return; object ids index the bodies ``object_<i>``, -1 = table or nothing.

The sensor model and the frame types load without MuJoCo; the renderers (``make_renderer``) import it
when first used, and MJX only for the ``mjx`` and ``warp`` backends.
"""

import importlib

from jaxcls.world.render.sensor import SensorConfig, apply_sensor, perturb_poses
from jaxcls.world.render.types import BACKENDS, Backend, DepthFrames, Renderer

__all__ = [
    "BACKENDS",
    "Backend",
    "DepthFrames",
    "Renderer",
    "SensorConfig",
    "apply_sensor",
    "default_backend",
    "make_renderer",
    "object_ids_of_geoms",
    "perturb_poses",
    "resolve_backend",
]

_LAZY = {"object_ids_of_geoms": "contract", "default_backend": "factory", "make_renderer": "factory",
         "resolve_backend": "factory"}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f"jaxcls.world.render.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'jaxcls.world.render' has no attribute {name!r}")
