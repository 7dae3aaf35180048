"""Depth rendering of static tabletop scenes: MuJoCo C ray casting, MJX ray casting, MJX's Warp renderer.

Conventions (DESIGN.md): metres; OpenCV cameras given by camera-to-world ``T_wc``; depth is z-depth,
0 = no return; object ids index the bodies ``object_<i>``, -1 = table or nothing.
"""

from jaxcls.render.contract import object_ids_of_geoms
from jaxcls.render.factory import default_backend, make_renderer, resolve_backend
from jaxcls.render.sensor import SensorConfig, apply_sensor, perturb_poses
from jaxcls.render.types import BACKENDS, Backend, DepthFrames, Renderer

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
