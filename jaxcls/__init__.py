"""jaxcls: active 3D classification of multiple objects in cluttered scenes, in pure-functional JAX.

The modules follow the pipeline (``../shared/DESIGN.md``): ``assets`` (object sets) -> ``scenes``
(cluttered tables as MuJoCo models) -> ``render`` (depth and object ids; sensor model) -> ``dataset`` /
``recording`` (frames on disk) -> ``tsdf`` (fusion, surface extraction). ``geometry`` holds cameras,
poses and viewpoints; ``config`` the YAML configs; ``cli`` the ``jaxcls`` command.
"""

from jaxcls import assets, config, dataset, geometry, recording, render, scenes, tsdf

__version__ = "0.1.0"

__all__ = ["assets", "config", "dataset", "geometry", "recording", "render", "scenes", "tsdf"]
