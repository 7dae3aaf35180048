"""Backend ``mujoco``: MuJoCo's C ray caster (``mj_multiRay``), one call per frame, frames over threads.

Found empirically (MuJoCo 4.0.0):
- ``mj_multiRay`` takes unnormalised directions and returns the ray parameter ``x`` of the hit
  ``pnt + x * vec``. With ``vec = R_wc @ pixel_rays`` (camera z = 1) that parameter is the z-depth itself.
- ``cutoff`` culls geoms whose bounding sphere lies beyond it; it is no depth limit. We pass mjMAXVAL.
- The binding releases the GIL during the call, so threads scale; each thread needs its own ``MjData``
  (the call allocates on the data's stack).
- Every ray costs about 0.2 us before it meets any geom (two atan2 for the angular culling, per-body
  sphere tests): 60 ms for a 640x480 frame of a bare table. So only the pixels inside the projected
  bounding boxes of the objects go through ``mj_multiRay``; the others can only see the table, a box,
  which is intersected in closed form (``cull=False`` casts every pixel in C).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np

from jaxcls.geometry import Intrinsics, pixel_rays
from jaxcls.world.render import contract
from jaxcls.world.render.types import NO_DEPTH, NO_OBJECT, Backend, DepthFrames

# Rays per block of the closed-form table pass: 8 f64 work rows of this length fit in L2 cache.
_BLOCK = 8192
# Corners closer than this to the camera plane (m) make the projected box unbounded: cast every pixel.
_NEAR = 1e-6


def available_cores() -> int:
    """Cores this process may run on (the affinity mask, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


class NativeRenderer:
    """Depth and object ids by ``mj_multiRay`` from the camera centre through every pixel.

    The scene is static: geom poses are set once by ``mj_forward``; the camera pose is only a ray origin
    and direction, so the mocap body is never moved.
    """

    backend: Backend = Backend.mujoco

    def __init__(self, model: mujoco.MjModel, intrinsics: Intrinsics, workers: int | None = None,
                 cull: bool = True):
        if workers is not None and workers < 1:
            raise ValueError(f"workers must be >= 1 or None (all cores), got {workers}")
        self.intrinsics = intrinsics
        self.workers = workers or available_cores()
        self._model = contract.render_model(model)
        self._geom_object = np.append(contract.object_ids_of_geoms(self._model), NO_OBJECT).astype(np.int32)
        self._rays = np.ascontiguousarray(pixel_rays(intrinsics).reshape(-1, 3))  # [N, 3], z = 1
        self._rays_t = np.ascontiguousarray(self._rays.T)  # [3, N]
        self._geomgroup = np.array(contract.GEOMGROUP_MASK, np.uint8)
        self._data = [self._make_data() for _ in range(self.workers)]
        self._table = _table_box(self._model, self._data[0]) if cull else None
        self._corners = _object_corners(self._model, self._data[0])  # [K, 8, 3] world

    def _make_data(self) -> mujoco.MjData:
        data = mujoco.MjData(self._model)
        mujoco.mj_forward(self._model, data)
        return data

    def render(self, T_wc: np.ndarray) -> DepthFrames:
        """T_wc: [B, 4, 4] | [4, 4] OpenCV camera-to-world. Returns NumPy [B, H, W] f32 depth, i32 ids."""
        T = contract.check_poses(T_wc)
        B, H, W = T.shape[0], self.intrinsics.height, self.intrinsics.width
        depth = np.empty((B, H * W), np.float32)
        object_id = np.empty((B, H * W), np.int32)
        n_workers = min(self.workers, B)
        chunks = np.array_split(np.arange(B), n_workers)
        if n_workers == 1:
            self._render_frames(self._data[0], T, chunks[0], depth, object_id)
        else:
            with ThreadPoolExecutor(n_workers) as pool:
                futures = [pool.submit(self._render_frames, data, T, idx, depth, object_id)
                           for data, idx in zip(self._data, chunks, strict=False)]
                for future in futures:
                    future.result()
        return DepthFrames(depth=depth.reshape(B, H, W), object_id=object_id.reshape(B, H, W))

    def _render_frames(self, data: mujoco.MjData, T: np.ndarray, frames: np.ndarray,
                       depth: np.ndarray, object_id: np.ndarray) -> None:
        """Fill rows ``frames`` of depth/object_id [B, N] in place, casting with this thread's ``data``."""
        scratch = np.empty((8, _BLOCK))
        for b in frames:
            R, origin = T[b, :3, :3], np.ascontiguousarray(T[b, :3, 3])
            if self._table is None:
                cast = np.arange(self._rays.shape[0])
            else:  # the table everywhere in closed form, then the C caster where objects may be
                for start in range(0, self._rays.shape[0], _BLOCK):  # blocks that stay in cache
                    rays = self._rays_t[:, start:start + _BLOCK]
                    t = _ray_box(origin, R, rays, *self._table, scratch[:, : rays.shape[1]])
                    t[np.isinf(t)] = NO_DEPTH
                    depth[b, start:start + _BLOCK] = t
                object_id[b] = NO_OBJECT
                cast = np.flatnonzero(self._object_pixels(T[b]))
            n = cast.size
            if n == 0:
                continue
            geom = np.empty(n, np.int32)
            dist = np.empty(n, np.float64)
            vec = np.ascontiguousarray(self._rays[cast] @ R.T).reshape(-1)
            mujoco.mj_multiRay(self._model, data, origin, vec, self._geomgroup, 1, -1, geom, dist, None, n,
                               mujoco.mjMAXVAL)
            depth[b, cast] = np.where(geom >= 0, dist, NO_DEPTH)
            object_id[b, cast] = self._geom_object[geom]  # geom -1 indexes the appended NO_OBJECT

    def _object_pixels(self, T_wc: np.ndarray) -> np.ndarray:
        """[N] bool: pixels inside the image rectangle bounding some object's projected box (1 px margin).
        The projection of a box in front of the camera lies inside the hull of its projected corners."""
        intr = self.intrinsics
        mask = np.zeros((intr.height, intr.width), bool)
        corners = (self._corners - T_wc[:3, 3]) @ T_wc[:3, :3]  # [K, 8, 3] camera frame
        for box in corners:
            if np.any(box[:, 2] < _NEAR):
                return np.ones(intr.height * intr.width, bool)
            u, v = intr.project(box[:, 0], box[:, 1], 1.0 / box[:, 2])
            u0, u1 = max(int(np.floor(u.min())) - 1, 0), min(int(np.ceil(u.max())) + 2, intr.width)
            v0, v1 = max(int(np.floor(v.min())) - 1, 0), min(int(np.ceil(v.max())) + 2, intr.height)
            if u0 < u1 and v0 < v1:
                mask[v0:v1, u0:u1] = True
        return mask.reshape(-1)


def _object_corners(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """[K, 8, 3] world corners of the bounding box (``geom_aabb``) of every object geom."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    boxes = []
    for g in np.nonzero(contract.object_ids_of_geoms(model) >= 0)[0]:
        center, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        local = center + signs * half
        boxes.append(local @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g])
    return np.asarray(boxes).reshape(-1, 8, 3)


def _table_box(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(centre [3], rotation [3, 3], half sizes [3]) of the table box; None if there is no box table."""
    g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, contract.TABLE_GEOM)
    if g < 0 or model.geom_type[g] != mujoco.mjtGeom.mjGEOM_BOX:
        return None
    return data.geom_xpos[g].copy(), data.geom_xmat[g].reshape(3, 3).copy(), model.geom_size[g].copy()


def _ray_box(origin: np.ndarray, R_wc: np.ndarray, rays_t: np.ndarray, center: np.ndarray, R: np.ndarray,
             half: np.ndarray, scratch: np.ndarray) -> np.ndarray:
    """[N] ray parameter of the first hit of ``origin + t R_wc rays_t[:, n]`` with an oriented box
    (centre, rotation ``R``, half sizes), inf if none. rays_t: [3, N] camera-frame directions;
    scratch: [8, N] f64 work space, the result is a view into it.

    Slab method in the box frame; a ray starting inside hits its exit face, as in MuJoCo's ``ray_box``.
    In float64 like MuJoCo (float32 flips the odd ray grazing the table's edge). Every array lives in
    ``scratch`` (fresh multi-MB arrays page-fault on each frame and serialise the threads); callers pass
    blocks of rays that keep it in cache.
    """
    o = (origin - center) @ R
    lo, hi = -half - o, half - o
    d, t_near, t_far, t1, t2, tmp = scratch[:3], scratch[3], scratch[4], scratch[5], scratch[6], scratch[7]
    np.matmul(R.T @ R_wc, rays_t, out=d)  # [3, N]: one contiguous row per axis of the box frame
    t_near.fill(-np.inf)
    t_far.fill(np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for i in range(3):
            np.divide(1.0, d[i], out=tmp)
            np.multiply(tmp, lo[i], out=t1)
            np.multiply(tmp, hi[i], out=t2)
            np.fmin(t1, t2, out=tmp)  # fmin/fmax skip the NaN of 0 * inf
            np.fmax(t_near, tmp, out=t_near)
            np.fmax(t1, t2, out=tmp)
            np.fmin(t_far, tmp, out=t_far)
    # t_near if it is ahead, else t_far (the ray starts inside); inf where the slabs do not overlap
    miss = (t_near > t_far) | (t_far < 0)
    np.copyto(t2, t_far)
    np.copyto(t2, t_near, where=t_near >= 0)
    t2[miss] = np.inf
    return t2
