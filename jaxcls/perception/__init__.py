"""A move's perception (paper Sec. 3.1-3.2), one module per stage, composed by ``observe``.

- ``settings``: the config blocks (foreground, volume, segmentation, shapes) and the static ``Spec``;
- ``tracking``: register each frame to the fused model (and the table) before fusion; hand-eye estimate;
- ``foreground``: drop background and table pixels and points;
- ``tsdf``: fuse posed depth frames into a TSDF; extract surface points with normals;
- ``segment``: split the surface into N object segments (reference path and its JAX twin);
- ``pointnet``: PointNet class scores of segments and top-k candidates (weights shipped in ``weights/``);
- ``observation``: the chain above as one pure function, ``perceive`` (``observe``: from the host, the frame
  validated first), over an ``Observation`` state;
- ``pose``: initial model poses of a segment (upright on the table, yaw hypotheses);
- ``icp``: point-to-plane ICP of a segment onto a model and the registration ratio (Eq. 2);
- ``refine``: geometric refinement, every candidate registered in one call (Eq. 2-4).

Perception imports the top-level helpers (``geometry``, ``math``, ``config``, ``io``), never the world,
training, the episode or the commands.
"""

from jaxcls.perception import (
    foreground,
    icp,
    observation,
    pointnet,
    pose,
    refine,
    segment,
    settings,
    tracking,
    tsdf,
)
from jaxcls.perception.observation import Observation, empty_volume, init_state, observe, perceive
from jaxcls.perception.settings import (
    ForegroundConfig,
    PerceptionConfig,
    SegmentConfig,
    ShapeConfig,
    Spec,
    VolumeConfig,
)
from jaxcls.perception.tracking import TrackingConfig

__all__ = ["ForegroundConfig", "Observation", "PerceptionConfig", "SegmentConfig", "ShapeConfig", "Spec",
           "TrackingConfig", "VolumeConfig", "empty_volume", "foreground", "icp", "init_state", "observation",
           "observe", "perceive", "pointnet", "pose", "refine", "segment", "settings", "tracking", "tsdf"]
