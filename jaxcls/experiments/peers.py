"""The peer compositions the benchmarks time ours against, in the libraries a practitioner would reach for:

- ``Open3DTracker``: frame-to-model camera tracking with Open3D's point-to-plane ICP (``benchmarks/tracking.py``,
  and the peer's reconstruction in ``benchmarks/move.py``);
- ``open3d_refine``: Eq. 2-4 with Open3D's ICP, one registration after another, rho from SciPy KD-trees
  (``benchmarks/refine.py``, the peer's GR in ``benchmarks/move.py``); ``HostTarget`` and ``HostPose`` give it
  NumPy inputs;
- ``numpy_paper``: the paper's visibility count (Eq. 5) in NumPy/SciPy (``benchmarks/nbv.py``, the peer's NBV in
  ``benchmarks/move.py``).

Open3D is imported where it is used (a development dependency).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import ConvexHull, cKDTree

from jaxcls import geometry
from jaxcls.geometry import Intrinsics
from jaxcls.perception import pose, refine

MAX_CORRESPONDENCE = 0.02  # m, Open3D's pair gate in tracking (ours: 0.01 at the finest level, x2 per coarser level)
ITERATIONS = 20  # Open3D's most ICP iterations in tracking (ours: 3 levels x 5 Gauss-Newton steps)
STRIDE = 2  # every n-th pixel of the frame is a source point (ours' finest level)


# --------------------------------------------------------------------------- camera tracking


class Open3DTracker:
    """Frame-to-model registration with Open3D: the frame's foreground points (every ``stride``-th pixel, camera
    frame) onto the model's points with normals, point-to-plane ICP from the initial pose."""

    def __init__(self, intrinsics: Intrinsics, floor: float, max_depth: float, stride: int = STRIDE,
                 max_correspondence: float = MAX_CORRESPONDENCE, iterations: int = ITERATIONS,
                 huber: float | None = None):
        import open3d as o3d

        self.o3d, self.reg = o3d, o3d.pipelines.registration
        self.rays = np.asarray(geometry.pixel_rays(intrinsics), np.float64)[::stride, ::stride]
        self.stride, self.floor, self.max_depth = stride, floor, max_depth
        self.max_correspondence = max_correspondence
        self.criteria = self.reg.ICPConvergenceCriteria(1e-6, 1e-6, iterations)
        kernel = () if huber is None else (self.reg.HuberLoss(huber),)
        self.estimation = self.reg.TransformationEstimationPointToPlane(*kernel)

    def source(self, depth: np.ndarray, T_init: np.ndarray):
        """The frame's foreground points in the camera frame: depth within range, world z above the floor."""
        d = np.asarray(depth, np.float64)[::self.stride, ::self.stride]
        ok = np.isfinite(d) & (d > 0) & (d <= self.max_depth)
        d = np.where(ok, d, 0.0)
        points = self.rays * d[..., None]
        T = np.asarray(T_init, np.float64)
        ok &= points @ T[2, :3] + T[2, 3] > self.floor
        return self.o3d.geometry.PointCloud(self.o3d.utility.Vector3dVector(points[ok]))

    def target(self, points: np.ndarray, normals: np.ndarray):
        """The model as Open3D's point cloud with normals (points, normals: [P, 3], real rows only)."""
        cloud = self.o3d.geometry.PointCloud(self.o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
        cloud.normals = self.o3d.utility.Vector3dVector(np.asarray(normals, np.float64))
        return cloud

    def icp(self, source, target, T_init: np.ndarray):
        """Open3D's ``RegistrationResult``: ``transformation`` is the registered T_wc."""
        return self.reg.registration_icp(source, target, self.max_correspondence, np.asarray(T_init, np.float64),
                                         self.estimation, self.criteria)

    def register(self, depth: np.ndarray, T_init: np.ndarray, points: np.ndarray, normals: np.ndarray
                 ) -> np.ndarray:
        """[4, 4] T_wc of the frame registered to the model from ``T_init`` (``T_init`` itself with < 3 model
        or frame points)."""
        source = self.source(depth, T_init)
        if len(points) < 3 or len(source.points) < 3:
            return np.asarray(T_init, np.float64)
        return np.asarray(self.icp(source, self.target(points, normals), T_init).transformation)


# --------------------------------------------------------------------------- geometric refinement


def open3d_refine(points, mask, probs, models, targets, config: refine.RefineConfig, table_height: float,
                  poses=pose):
    """Eq. 2-4 with Open3D's ICP, one registration after another: (refined class [N], pose [N, 4, 4]). ``targets``:
    each class's ``icp.Target`` (or anything with its ``samples()``); ``poses``: the module whose
    ``initial_poses`` and ``even_yaws`` give the initial poses (``pose``, or ``HostPose`` in NumPy)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    clouds = []
    for t in targets:
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(t.samples()[0], np.float64)))
        cloud.normals = o3d.utility.Vector3dVector(np.asarray(t.samples()[1], np.float64))
        clouds.append((cloud, cKDTree(np.asarray(t.samples()[0], np.float64))))
    criteria = reg.ICPConvergenceCriteria(1e-6, 1e-6, 30)
    refined, aligned = [], []
    for n in range(len(points)):
        seen = points[n][mask[n]].astype(np.float64)
        if len(seen) < 3:
            refined.append(int(np.argmax(probs[n])))
            aligned.append(np.eye(4))
            continue
        source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(seen))
        best = (-1.0, 0, np.eye(4))
        for c in np.argsort(-probs[n])[: config.top_k]:
            cloud, tree = clouds[c]
            inits = np.asarray(poses.initial_poses(points[n], mask[n], np.asarray(targets[c].samples()[0]).mean(0),
                                                   table_height, poses.even_yaws(config.hypotheses)), np.float64)
            for T0 in inits:
                result = reg.registration_icp(source, cloud, config.icp.max_correspondence, np.linalg.inv(T0),
                                              reg.TransformationEstimationPointToPlane(), criteria)
                T = result.transformation
                moved = seen @ T[:3, :3].T + T[:3, 3]
                near = tree.query(moved)[0] <= config.icp.inlier_distance
                covered = cKDTree(moved).query(np.asarray(cloud.points))[0] <= config.icp.inlier_distance
                rho = near.mean() * covered.mean()
                if rho > best[0]:
                    best = (rho, int(c), np.linalg.inv(T))
        refined.append(best[1])
        aligned.append(best[2])
    return np.asarray(refined), np.stack(aligned)


@dataclasses.dataclass(frozen=True)
class HostTarget:
    """A model's samples in NumPy: what ``open3d_refine`` reads of an ``icp.Target`` (``samples()``), without
    JAX's eager indexing on every call."""

    points: np.ndarray
    normals: np.ndarray
    mask: np.ndarray

    def samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.points, self.normals, self.mask


class HostPose:
    """``pose.even_yaws`` and ``pose.initial_poses`` in NumPy (the same formulas), for ``open3d_refine``'s
    ``poses``: called eagerly per (segment, model), the JAX ones cost ~0.2 s of dispatch a move."""

    @staticmethod
    def even_yaws(hypotheses: int) -> np.ndarray:
        return 2 * np.pi * np.arange(hypotheses) / hypotheses

    @staticmethod
    def initial_poses(points, mask, centroid, table_height, yaws) -> np.ndarray:
        w = np.asarray(mask, np.float64)
        total = w.sum()
        c = (w[:, None] * points).sum(axis=0) / total if total > 0 else np.zeros(3)
        cos, sin = np.cos(yaws), np.sin(yaws)
        T = np.tile(np.eye(4), (len(yaws), 1, 1))
        T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = cos, -sin, sin, cos
        T[:, :2, 3] = c[:2] - T[:, :2, :2] @ np.asarray(centroid, np.float64)[:2]
        T[:, 2, 3] = table_height
        return T


# --------------------------------------------------------------------------- next-best-view


def numpy_paper(corners: np.ndarray, poses: np.ndarray, T_wc: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """[V, N] the paper's count in NumPy/SciPy (every cuboid in front of the camera)."""
    v, u = np.mgrid[0:intrinsics.height, 0:intrinsics.width]
    pixels = np.stack([u.ravel(), v.ravel()], -1).astype(np.float64)
    out = np.zeros((len(T_wc), len(corners)))
    for i, T in enumerate(np.asarray(T_wc, np.float64)):
        inv = np.linalg.inv(T)
        cams = [((inv @ p)[:3, :3] @ c.T + (inv @ p)[:3, 3:4]) for c, p in zip(corners, poses, strict=True)]
        free = np.ones(len(pixels), bool)
        for n in sorted(range(len(corners)), key=lambda n: cams[n][2].mean()):
            c = cams[n]
            uv = np.stack([intrinsics.fx * c[0] / c[2] + intrinsics.cx,
                           intrinsics.fy * c[1] / c[2] + intrinsics.cy], -1)
            eq = ConvexHull(uv).equations
            inside = free & np.all(pixels @ eq[:, :2].T + eq[:, 2] <= 1e-9, axis=1)
            out[i, n] = inside.sum()
            free &= ~inside
    return out
