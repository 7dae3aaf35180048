"""Camera model, poses and the viewpoint hemisphere.

Conventions (docs/ARCHITECTURE.md): metres; world z up; OpenCV camera (x right, y down, z forward); a camera pose is
the 4x4 camera-to-world transform ``T_wc``. Functions take ``...`` leading batch axes.

Poses have one representation, ``jaxlie`` (``SE3``/``SO3`` below, with ``...`` batch axes):

- at module boundaries (arrays handed between modules, datasets, MuJoCo) a pose is a ``[..., 4, 4]`` matrix
  such as ``T_wc``;
- where poses are composed, inverted or updated on the tangent space it is a ``jaxlie.SE3``
  (``pose_from_matrix(T)``, ``a @ b``, ``.inverse()``, ``SE3.exp``, ``.log()``, ``jaxlie.manifold.rplus``), and
  ``.as_matrix()`` turns it back. Tangent vectors are ``[..., 6]`` in jaxlie's order: translation part
  first, then rotation (axis-angle), ``(v_x, v_y, v_z, w_x, w_y, w_z)``; ``SE3.exp`` couples them (its
  translation is ``V(w) v``, not ``v``), and ``rplus(T, d)`` is ``T @ SE3.exp(d)`` (a body-frame update).

Exact float64 host code (scene layout, MuJoCo bodies) stays in NumPy (``yaw_matrix_np``): JAX's default
float32 would round it. Gradient-safe norms and divisions live in ``jaxcls.math``.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from flax import struct

from jaxcls import devices
from jaxcls.config import bounded, check_bounds
from jaxcls.math import row_dots

# MuJoCo cameras look along their -z with y up; OpenCV cameras look along +z with y down. The same
# matrix maps back (it is its own inverse).
CV_TO_MJ = np.diag([1.0, -1.0, -1.0])


@struct.dataclass
class Intrinsics:
    """Pinhole intrinsics in pixels; pixel (u, v) has its centre at integer coordinates.

    All fields are static, so a change of sensor recompiles and a pose batch does not.
    """

    width: int = struct.field(pytree_node=False)
    height: int = struct.field(pytree_node=False)
    fx: float = struct.field(pytree_node=False)
    fy: float = struct.field(pytree_node=False)
    cx: float = struct.field(pytree_node=False)
    cy: float = struct.field(pytree_node=False)

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
                raise ValueError(f"Intrinsics: {name} must be an integer >= 1 (pixels), got {value!r}")
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
                raise ValueError(f"Intrinsics: {name} must be a finite number (pixels), got {value!r}")
            if name in ("fx", "fy") and value <= 0:
                raise ValueError(f"Intrinsics: {name} must be > 0 (pixels), got {value!r}")

    @classmethod
    def kinect_v1(cls, scale: float = 1.0) -> Intrinsics:
        """Kinect v1 (640x480, f = 525 px); ``scale`` < 1 gives the same field of view at lower resolution."""
        return cls.from_fovy(round(640 * scale), round(480 * scale), fovy_deg=fovy_deg(525.0, 480))

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy_deg: float) -> Intrinsics:
        """Square pixels, principal point at the image centre: the camera model MuJoCo renders."""
        f = 0.5 * height / math.tan(math.radians(fovy_deg) / 2)
        return cls(width=width, height=height, fx=f, fy=f, cx=(width - 1) / 2, cy=(height - 1) / 2)

    @property
    def fovy_deg(self) -> float:
        return fovy_deg(self.fy, self.height)

    @property
    def matrix(self) -> np.ndarray:
        """[3, 3] the OpenCV camera matrix K."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]])

    def project(self, x: np.ndarray | jax.Array, y: np.ndarray | jax.Array, inv_z: np.ndarray | jax.Array
                ) -> tuple[np.ndarray | jax.Array, np.ndarray | jax.Array]:
        """(u, v) pixel coordinates of camera-frame coordinates ``x, y`` (m) with ``inv_z`` = 1 / z (the caller
        guards z <= 0): the OpenCV pinhole, u = fx x / z + cx, v = fy y / z + cy. NumPy or JAX, any shape."""
        return self.fx * x * inv_z + self.cx, self.fy * y * inv_z + self.cy

    def validate_mujoco(self) -> None:
        """MuJoCo renders square pixels about the image centre; anything else cannot be rendered exactly."""
        if not (math.isclose(self.fx, self.fy, rel_tol=1e-6)
                and math.isclose(self.cx, (self.width - 1) / 2, abs_tol=1e-6)
                and math.isclose(self.cy, (self.height - 1) / 2, abs_tol=1e-6)):
            raise ValueError(f"MuJoCo cameras need fx == fy and a centred principal point, got {self}")


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """A pinhole sensor; the default is the paper's Kinect v1 (640x480, f = 525 px)."""

    width: int = bounded(640, ge=1)
    height: int = bounded(480, ge=1)
    fx: float = bounded(525.0, gt=0.0)
    fy: float = bounded(525.0, gt=0.0)
    cx: float = bounded(319.5)  # finite
    cy: float = bounded(239.5)

    def __post_init__(self) -> None:
        check_bounds(self, "camera.")

    def intrinsics(self) -> Intrinsics:
        return Intrinsics(width=self.width, height=self.height, fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy)

    @classmethod
    def from_intrinsics(cls, intrinsics: Intrinsics) -> CameraConfig:
        """The config block of ``intrinsics``."""
        k = intrinsics
        return cls(width=k.width, height=k.height, fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy)

    @classmethod
    def kinect_v1(cls, scale: float = 1.0) -> CameraConfig:
        """The Kinect v1 (``Intrinsics.kinect_v1``); ``scale`` < 1: the same field of view, fewer pixels."""
        return cls.from_intrinsics(Intrinsics.kinect_v1(scale))


@dataclasses.dataclass(frozen=True)
class ViewpointConfig:
    """The view hemisphere around the scene centroid (paper Sec. 4: 100 views, r = 1 m, z >= 0)."""

    count: int = bounded(100, ge=1)
    radius: float = bounded(1.0, gt=0.0)
    min_elevation_deg: float = bounded(0.0, ge=0.0, lt=90.0)

    def __post_init__(self) -> None:
        check_bounds(self, "viewpoints.")


def fovy_deg(fy: float, height: int) -> float:
    """Vertical field of view in degrees of a pinhole with focal length ``fy`` px over ``height`` rows."""
    return math.degrees(2 * math.atan(0.5 * height / fy))


def pixel_rays(intrinsics: Intrinsics) -> np.ndarray:
    """[H, W, 3] ray directions in the camera frame, scaled so that their z is 1 (z-depth = ray length)."""
    u = (np.arange(intrinsics.width) - intrinsics.cx) / intrinsics.fx
    v = (np.arange(intrinsics.height) - intrinsics.cy) / intrinsics.fy
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu, vv, np.ones_like(uu)], axis=-1)


def invert_rigid(T: jax.Array) -> jax.Array:
    """The inverse of a rigid transform ``T: [4, 4]`` in closed form (R^T, -R^T t)."""
    R, t = T[:3, :3], T[:3, 3]
    return jnp.eye(4, dtype=T.dtype).at[:3, :3].set(R.T).at[:3, 3].set(-R.T @ t)


def rotate(R: jax.Array, x: jax.Array, fused: bool | None = None) -> jax.Array:
    """``x @ R.T``: the [3, 3] matrix ``R`` applied to points ``x: [..., 3]`` at full float32 precision.

    On an accelerator as three products and two sums a coordinate, which XLA fuses into the operations around
    them: a matrix product of 3 terms is a kernel of its own on a GPU, at HIGHEST precision (``jaxcls.precision``)
    a slow one (the tracking's were ~7% of a batched move's GPU time, BENCHMARKS.md, issue 34). On the CPU the
    HIGHEST product itself: its rounding does not depend on vmap, the elementwise form's does (FMA contraction),
    and a vmapped move must equal the sequential one there (tests/test_episode.py). ``fused``: the elementwise
    form (True) or the product (False) whatever the backend (None: ``precision.fused_products``)."""
    return row_dots(x, R, fused)


def transform_points(T: jnp.ndarray, points: jnp.ndarray) -> jnp.ndarray:
    """Apply ``T: [..., 4, 4]`` to ``points: [..., P, 3]``."""
    return jnp.einsum("...ij,...pj->...pi", T[..., :3, :3], points) + T[..., None, :3, 3]


def backproject(depth: jnp.ndarray, intrinsics: Intrinsics, T_wc: jnp.ndarray) -> jnp.ndarray:
    """World points of a depth map.

    depth: [..., H, W] z-depth in metres (0 = no return); T_wc: [..., 4, 4].
    Returns [..., H, W, 3] world points; pixels without a return map to the camera centre.
    """
    depth = jnp.asarray(depth)
    rays = jnp.asarray(pixel_rays(intrinsics), depth.dtype)
    points_c = rays * depth[..., None]
    R, t = T_wc[..., :3, :3], T_wc[..., :3, 3]
    return jnp.einsum("...ij,...hwj->...hwi", R, points_c) + t[..., None, None, :]


# ---------------------------------------------------------------- rigid transforms (jaxlie)

SE3 = jaxlie.SE3
SO3 = jaxlie.SO3


def pose_from_matrix(T: jax.Array) -> jaxlie.SE3:
    """The ``SE3`` of rigid transforms ``T: [..., 4, 4]`` (the last row is assumed to be 0 0 0 1)."""
    return jaxlie.SE3.from_matrix(jnp.asarray(T))


def yaw_pose(yaw: jax.Array, translation: jax.Array) -> jaxlie.SE3:
    """``SE3`` rotating by ``yaw: [...]`` rad about world z, then translating by ``translation: [..., 3]``."""
    yaw, translation = _float(yaw), _float(translation)
    batch = jnp.broadcast_shapes(yaw.shape, translation.shape[:-1])
    rotation = jaxlie.SO3.from_z_radians(jnp.broadcast_to(yaw, batch))
    return jaxlie.SE3.from_rotation_and_translation(rotation, jnp.broadcast_to(translation, (*batch, 3)))


def yaw_rotation(yaw: jax.Array) -> jax.Array:
    """[..., 3, 3] rotations about the world z axis by ``yaw: [...]`` rad (counter-clockwise seen from above).

    Differentiable, with finite gradients at 0 (jaxlie's exp switches to its Taylor series there).
    """
    return jaxlie.SO3.from_z_radians(_float(yaw)).as_matrix()


def _float(x: jax.Array) -> jax.Array:
    """``x`` as a JAX array of at least float32 (jaxlie knows float32 and float64 only)."""
    x = jnp.asarray(x)
    return x.astype(jnp.promote_types(x.dtype, jnp.float32))


def yaw_matrix_np(yaw: np.ndarray) -> np.ndarray:
    """[..., 3, 3] float64 NumPy ``yaw_rotation``, for exact host-side poses (scene layout, MuJoCo bodies)."""
    yaw = np.asarray(yaw, np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros((*yaw.shape, 3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


def look_at(eye: np.ndarray | jax.Array, target: np.ndarray | jax.Array, up: np.ndarray = (0.0, 0.0, 1.0),
            xp=np) -> np.ndarray | jax.Array:
    """[..., 4, 4] ``T_wc`` of OpenCV cameras at ``eye: [..., 3]`` looking at ``target: [..., 3]``.

    Image "down" points along -``up``; a camera looking straight along ``up`` uses world y as its up. With
    NumPy (the default) an eye on its target is a ValueError; with ``xp=jax.numpy`` it is traceable and
    differentiable (the caller keeps the eye off the target).
    """
    eye, target = xp.broadcast_arrays(xp.asarray(eye, float), xp.asarray(target, float))
    forward = target - eye
    dist = xp.linalg.norm(forward, axis=-1, keepdims=True)
    if xp is np and np.any(dist < 1e-9):
        raise ValueError("look_at: eye and target coincide")
    forward = forward / dist
    up = xp.broadcast_to(xp.asarray(up, float), forward.shape)
    parallel = xp.abs(xp.sum(forward * up, axis=-1, keepdims=True)) > 1 - 1e-6
    up = xp.where(parallel, xp.asarray([0.0, 1.0, 0.0]), up)
    right = xp.cross(forward, up)
    right = right / xp.linalg.norm(right, axis=-1, keepdims=True)
    down = xp.cross(forward, right)
    top = xp.concatenate([xp.stack([right, down, forward], axis=-1), eye[..., None]], axis=-1)  # [..., 3, 4]
    bottom = xp.broadcast_to(xp.asarray([0.0, 0.0, 0.0, 1.0]), (*top.shape[:-2], 1, 4))
    return xp.concatenate([top, bottom], axis=-2)


def hemisphere_viewpoints(center: np.ndarray, count: int = 100, radius: float = 1.0,
                          min_elevation_deg: float = 0.0) -> np.ndarray:
    """[count, 4, 4] ``T_wc`` of near-uniform viewpoints on the upper hemisphere, each looking at ``center``.

    A Fibonacci lattice over the spherical zone above ``min_elevation_deg``: equal-area bands in z, golden-
    angle steps in azimuth (the paper's 100 views at r = 1 m, Sec. 4).
    """
    if count < 1 or radius <= 0 or not 0 <= min_elevation_deg < 90:
        raise ValueError(f"hemisphere_viewpoints: bad count={count}, radius={radius}, "
                         f"min_elevation_deg={min_elevation_deg}")
    z_min = math.sin(math.radians(min_elevation_deg))
    k = np.arange(count)
    z = z_min + (1 - z_min) * (k + 0.5) / count
    azimuth = k * math.pi * (3 - math.sqrt(5))
    ring = np.sqrt(1 - z**2)
    directions = np.stack([ring * np.cos(azimuth), ring * np.sin(azimuth), z], axis=-1)
    center = np.asarray(center, float)
    return look_at(center + radius * directions, center)


def opencv_to_mujoco_rotation(R_wc: np.ndarray) -> np.ndarray:
    """[..., 3, 3] rotation of the MuJoCo camera frame that sees what the OpenCV frame ``R_wc`` sees."""
    return np.asarray(R_wc) @ CV_TO_MJ


def rotation_to_quat(R: np.ndarray) -> np.ndarray:
    """[..., 4] float64 unit quaternions (w, x, y, z), MuJoCo's order, w >= 0, of rotations ``R: [..., 3, 3]``.

    Host side: ``jaxlie.SO3.from_matrix`` evaluated in float64 (a local x64 scope) on the host's CPU device (on
    a GPU machine it would wait for the work queued there), so float64 poses keep float64 accuracy in MuJoCo
    bodies.
    """
    R = np.asarray(R, np.float64)
    with jax.enable_x64(True), jax.default_device(devices.host_cpu()):
        q = np.asarray(jaxlie.SO3.from_matrix(jnp.asarray(R)).wxyz, np.float64)
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def is_rigid(T: np.ndarray, atol: float = 1e-4) -> np.ndarray:
    """[...] bool: ``T: [..., 4, 4]`` is finite, its rotation orthonormal with det +1, its last row 0 0 0 1."""
    T = np.asarray(T, float)
    R = T[..., :3, :3]
    finite = np.all(np.isfinite(T), axis=(-2, -1))
    ortho = np.all(np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)) < atol, axis=(-2, -1))
    det = np.abs(np.linalg.det(np.where(finite[..., None, None], R, np.eye(3))) - 1) < atol
    last = np.all(np.abs(T[..., 3, :] - np.array([0, 0, 0, 1.0])) < atol, axis=-1)
    return finite & ortho & det & last
