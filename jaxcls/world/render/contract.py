"""The scene contract as the renderers read it, and the checks at their boundary.

A scene is a ``mujoco.MjModel`` whose objects are bodies ``object_0``, ``object_1``, ... (one or more
geoms each), whose table is a box geom named ``table``, and whose depth camera ``depth`` rides a mocap
body ``camera`` (MuJoCo camera frame: looks along -z, y up). Every geom carries a material.
"""

from __future__ import annotations

import copy
import re

import mujoco
import numpy as np

from jaxcls.geometry import Intrinsics, is_rigid

CAMERA_BODY = "camera"
CAMERA_NAME = "depth"
TABLE_GEOM = "table"

# Renderers cast against their own copy of the model in which the object and table geoms are in group 0
# and every other geom is in group 5, so one group mask keeps rays off anything else (walls, markers).
RENDER_GROUP = 0
HIDDEN_GROUP = 5
GEOMGROUP_MASK = (1, 0, 0, 0, 0, 0)

_OBJECT_BODY = re.compile(r"object_(\d+)")


def object_ids_of_geoms(model: mujoco.MjModel) -> np.ndarray:
    """[ngeom] i32: object index i for the geoms of body ``object_i``, -1 for every other geom."""
    ids = np.full(model.ngeom, -1, np.int32)
    for g in range(model.ngeom):
        match = _OBJECT_BODY.fullmatch(model.body(int(model.geom_bodyid[g])).name)
        if match:
            ids[g] = int(match.group(1))
    return ids


def rendered_geoms(model: mujoco.MjModel) -> np.ndarray:
    """[ngeom] bool: the geoms a depth ray may hit, the objects' and the table."""
    table = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, TABLE_GEOM)
    mask = object_ids_of_geoms(model) >= 0
    if table >= 0:
        mask[table] = True
    return mask


def render_model(model: mujoco.MjModel) -> mujoco.MjModel:
    """A copy of ``model`` whose geom groups put the rendered geoms in RENDER_GROUP and hide the rest.

    Raises if the model has no object geom, or a rendered geom without a material (``mjx.ray`` needs one).
    """
    mask = rendered_geoms(model)
    if not np.any(object_ids_of_geoms(model) >= 0):
        raise ValueError("scene contract: no geom belongs to a body named object_<i>")
    no_material = [_geom_label(model, g) for g in np.nonzero(mask & (model.geom_matid < 0))[0]]
    if no_material:
        raise ValueError(f"scene contract: geoms without a material (mjx.ray needs one): {no_material}")
    out = copy.deepcopy(model)
    out.geom_group[:] = np.where(mask, RENDER_GROUP, HIDDEN_GROUP)
    return out


def depth_camera(model: mujoco.MjModel) -> tuple[int, int]:
    """(camera id, mocap id) of the camera ``depth`` on the mocap body ``camera``; raises if absent."""
    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, CAMERA_NAME)
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, CAMERA_BODY)
    if cam < 0 or body < 0:
        raise ValueError(f"scene contract: needs a mocap body {CAMERA_BODY!r} carrying a camera "
                         f"{CAMERA_NAME!r} (found camera id {cam}, body id {body})")
    mocap = int(model.body_mocapid[body])
    if mocap < 0 or int(model.cam_bodyid[cam]) != body:
        raise ValueError(f"scene contract: camera {CAMERA_NAME!r} must be on the mocap body {CAMERA_BODY!r}")
    if int(model.cam_mode[cam]) != mujoco.mjtCamLight.mjCAMLIGHT_FIXED:
        raise ValueError(f"scene contract: camera {CAMERA_NAME!r} must be fixed to its body (mode 'fixed')")
    return cam, mocap


def check_camera_matches(model: mujoco.MjModel, intrinsics: Intrinsics) -> int:
    """Camera id of ``depth`` once its MuJoCo projection equals ``intrinsics``; raises naming the mismatch.

    MuJoCo's own camera (the warp renderer's rays) is a centred square-pixel pinhole of vertical fov
    ``cam_fovy``; our rays come from ``intrinsics``, so the two must agree.
    """
    intrinsics.validate_mujoco()
    cam, _ = depth_camera(model)
    if int(model.cam_projection[cam]) != mujoco.mjtProjection.mjPROJ_PERSPECTIVE:
        raise ValueError(f"camera {CAMERA_NAME!r} must be a perspective camera")
    if np.any(model.cam_sensorsize[cam] != 0):
        raise ValueError(f"camera {CAMERA_NAME!r} must be defined by fovy, not sensorsize/focal")
    fovy = float(model.cam_fovy[cam])
    if not np.isclose(fovy, intrinsics.fovy_deg, atol=1e-4):
        raise ValueError(f"camera {CAMERA_NAME!r} has fovy {fovy:.6f} deg, intrinsics need "
                         f"{intrinsics.fovy_deg:.6f} deg")
    return cam


def check_poses(T_wc: np.ndarray) -> np.ndarray:
    """[B, 4, 4] f64 copy of ``T_wc: [B, 4, 4] | [4, 4]`` once every pose is a finite rigid transform."""
    T = np.asarray(T_wc, dtype=np.float64)
    if T.shape == (4, 4):
        T = T[None]
    if T.ndim != 3 or T.shape[1:] != (4, 4) or T.shape[0] == 0:
        raise ValueError(f"T_wc must have shape [B, 4, 4] or [4, 4] with B >= 1, got {T.shape}")
    if not np.all(np.isfinite(T)):
        bad = np.nonzero(~np.all(np.isfinite(T), axis=(1, 2)))[0]
        raise ValueError(f"T_wc has non-finite entries in poses {bad.tolist()}")
    rigid = is_rigid(T)
    if not np.all(rigid):
        raise ValueError(f"T_wc poses {np.nonzero(~rigid)[0].tolist()} are not rigid (rotation not "
                         "orthonormal with det +1, or last row not 0 0 0 1)")
    return T


def _geom_label(model: mujoco.MjModel, g: int) -> str:
    name = model.geom(int(g)).name
    return name or f"#{g} of body {model.body(int(model.geom_bodyid[g])).name!r}"
