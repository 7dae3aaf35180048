"""A Kinect-v1-like depth sensor on rendered depth: noise, disparity quantisation, dropout, pose error.

Pure jitted JAX on batches ([..., H, W]); runs wherever the renderer's frames are. The defaults follow:
- axial noise: Nguyen, Izadi, Lovell, "Modeling Kinect sensor noise for improved 3D reconstruction and
  tracking", 3DIMPVT 2012: sigma_z = 0.0012 + 0.0019 (z - 0.4)^2 m, plus 0.0001 / sqrt(z) *
  theta^2 / (pi/2 - theta)^2 m at incidence angle theta (their Eq. 6-7).
- quantisation: depth is triangulated from a disparity measured in 1/8 pixel (Khoshelham & Elberink,
  Sensors 2012) with f = 580 px and baseline b = 0.075 m, so the depth step is z^2 / (8 f b):
  2.9 mm at 1 m, 11.5 mm at 2 m.
- dropout: no return where the projector's pattern is broken: at depth discontinuities and at grazing
  incidence beyond about 75-80 degrees (Nguyen et al. report no data past about 70-80 degrees); outside
  the 0.4-4.5 m range.
- pose noise: the hand-eye calibration error of a robot-held camera, a small rotation and translation in
  the camera frame; the perturbed pose is the one the pipeline believes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from flax import struct

from jaxcls import devices
from jaxcls.config import Bounds, check_bounds
from jaxcls.geometry import Intrinsics, pixel_rays
from jaxcls.math import safe_div, safe_norm

# Depth differences in the same units as depth; 0 = no return. Normals of zero length are "unknown".
_TINY = 1e-12


def _static(default, *, ge: float | None = None, gt: float | None = None, le: float | None = None,
            lt: float | None = None):
    """A static (hashed) field with a range, seen by ``check_bounds`` and ``load_config`` like ``bounded``."""
    return struct.field(pytree_node=False, default=default, metadata={"bounds": Bounds(ge, gt, le, lt)})


@struct.dataclass
class SensorConfig:
    """Which sensor effects apply and their parameters (metres, pixels, degrees); every field static,
    so the config is a hashable jit constant and a change of it recompiles. Ranges are checked when it is
    built (``sensor.<field>`` in errors): probabilities in [0, 1], sigmas >= 0, min_depth < max_depth."""

    # Axial noise sigma_z(z) = sigma_base + sigma_quad (z - sigma_z0)^2 (+ the incidence-angle term).
    axial_noise: bool = struct.field(pytree_node=False, default=True)
    sigma_base: float = _static(0.0012, ge=0.0)
    sigma_quad: float = _static(0.0019, ge=0.0)
    sigma_z0: float = _static(0.4, ge=0.0)
    angle_noise: bool = struct.field(pytree_node=False, default=True)
    sigma_angle: float = _static(0.0001, ge=0.0)
    # Disparity quantisation: depth = focal * baseline / disparity, disparity in 1/subpixel px steps.
    quantize: bool = struct.field(pytree_node=False, default=True)
    focal_px: float = _static(580.0, gt=0.0)
    baseline: float = _static(0.075, gt=0.0)
    subpixel: int = _static(8, ge=1)
    # Dropout at discontinuities: a 4-neighbour differs by more than edge_jump * z (or has no return);
    # the band is edge_width px wide and each pixel in it is lost with probability edge_prob.
    edge_dropout: bool = struct.field(pytree_node=False, default=True)
    edge_jump: float = _static(0.03, gt=0.0)
    edge_width: int = _static(1, ge=1)
    edge_prob: float = _static(1.0, ge=0.0, le=1.0)
    # Dropout at grazing incidence: the angle between the surface normal (from depth gradients) and the
    # viewing ray exceeds max_incidence_deg.
    grazing_dropout: bool = struct.field(pytree_node=False, default=True)
    max_incidence_deg: float = _static(78.0, gt=0.0, le=90.0)
    # Range limits (no return outside) and uniform random dropout.
    range_limits: bool = struct.field(pytree_node=False, default=True)
    min_depth: float = _static(0.4, gt=0.0)
    max_depth: float = _static(4.5, gt=0.0)
    random_dropout: float = _static(0.0, ge=0.0, le=1.0)
    # Camera-pose error (hand-eye calibration): rotation sigma per axis (deg), translation sigma per axis
    # (m), in the camera frame; shared = one error for the whole batch (a fixed calibration offset).
    pose_noise: bool = struct.field(pytree_node=False, default=False)
    pose_rot_sigma_deg: float = _static(0.3, ge=0.0)
    pose_trans_sigma: float = _static(0.003, ge=0.0)
    pose_noise_shared: bool = struct.field(pytree_node=False, default=False)

    def __post_init__(self) -> None:
        check_bounds(self, "sensor.")
        if not self.min_depth < self.max_depth:
            raise ValueError(f"sensor.min_depth ({self.min_depth}) must be < sensor.max_depth ({self.max_depth})")

    @classmethod
    def ideal(cls) -> SensorConfig:
        """Every effect off: ``apply_sensor`` and ``perturb_poses`` return their input unchanged."""
        return cls(axial_noise=False, angle_noise=False, quantize=False, edge_dropout=False,
                   grazing_dropout=False, range_limits=False, random_dropout=0.0, pose_noise=False)

    def sigma_z(self, z: jax.Array) -> jax.Array:
        """Axial noise sigma in metres at z-depth ``z`` (m), without the incidence-angle term."""
        return self.sigma_base + self.sigma_quad * (z - self.sigma_z0) ** 2

    def depth_step(self, z: jax.Array) -> jax.Array:
        """Quantisation step of depth in metres at ``z``: one disparity step, z^2 / (subpixel f b)."""
        return z**2 / (self.subpixel * self.focal_px * self.baseline)


@jax.jit
def apply_sensor(key: jax.Array, depth: jax.Array, intrinsics: Intrinsics, config: SensorConfig) -> jax.Array:
    """Measured depth [..., H, W] f32 from rendered z-depth ``depth: [..., H, W]`` (m, 0 = no return).

    Masks come from the clean depth, noise and quantisation from the noisy one; 0 stays 0, and a noisy
    value that leaves the measurable range becomes 0 too. Never NaN. ``key``: one PRNG key for the batch.
    """
    depth = jnp.asarray(depth, jnp.float32)
    if depth.ndim < 2 or depth.shape[-2:] != (intrinsics.height, intrinsics.width):
        raise ValueError(f"apply_sensor: depth has shape {tuple(depth.shape)}, the intrinsics need "
                         f"[..., {intrinsics.height}, {intrinsics.width}]")
    k_noise, k_edge, k_drop = jax.random.split(key, 3)
    valid = depth > 0
    cos_incidence = None
    if config.grazing_dropout or (config.axial_noise and config.angle_noise):
        cos_incidence = _cos_incidence(depth, intrinsics)

    z = depth
    if config.axial_noise:
        sigma = config.sigma_z(depth)
        if config.angle_noise:
            theta = jnp.arccos(jnp.clip(cos_incidence, 0.0, 1.0))
            ratio = theta / jnp.maximum(jnp.pi / 2 - theta, 1e-3)
            sigma = sigma + config.sigma_angle * ratio**2 / jnp.sqrt(jnp.maximum(depth, 1e-3))
        z = depth + sigma * jax.random.normal(k_noise, depth.shape, depth.dtype)
    if config.quantize:
        z = _quantize(z, config)

    keep = valid & jnp.isfinite(z) & (z > 0)
    if config.range_limits:
        keep &= (z >= config.min_depth) & (z <= config.max_depth)
    if config.edge_dropout:
        edge = _dilate(_discontinuities(depth, config.edge_jump), config.edge_width - 1)
        lost = jax.random.bernoulli(k_edge, config.edge_prob, depth.shape)
        keep &= ~(edge & lost)
    if config.grazing_dropout:
        keep &= cos_incidence >= math.cos(math.radians(config.max_incidence_deg))
    if config.random_dropout > 0:
        keep &= ~jax.random.bernoulli(k_drop, config.random_dropout, depth.shape)
    return jnp.where(keep, z, 0.0)


@jax.jit
def perturb_poses(key: jax.Array, T_wc: jax.Array, config: SensorConfig) -> jax.Array:
    """Believed poses [..., 4, 4]: ``T_wc @ dT`` with dT a random rigid motion in the camera frame.

    The rotation is exp of an axis-angle vector with N(0, pose_rot_sigma) components, the translation
    N(0, pose_trans_sigma) per axis; one dT for the whole batch if ``pose_noise_shared``. Identity if off.
    """
    T_wc = jnp.asarray(T_wc)
    if not config.pose_noise:
        return T_wc
    batch = () if config.pose_noise_shared else T_wc.shape[:-2]
    k_rot, k_trans = jax.random.split(key)
    omega = math.radians(config.pose_rot_sigma_deg) * jax.random.normal(k_rot, (*batch, 3), T_wc.dtype)
    trans = config.pose_trans_sigma * jax.random.normal(k_trans, (*batch, 3), T_wc.dtype)
    dT = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.exp(omega), trans).as_matrix().astype(T_wc.dtype)
    return jnp.matmul(T_wc, dT, precision=jax.lax.Precision.HIGHEST)  # not TF32 on GPUs


def _quantize(z: jax.Array, config: SensorConfig) -> jax.Array:
    """Depth through the sensor's disparity: d = f b / z rounded to 1/subpixel px, back to depth."""
    fb = config.focal_px * config.baseline
    disparity = fb / jnp.where(z > 0, z, 1.0)
    steps = jnp.round(disparity * config.subpixel)
    return jnp.where((z > 0) & (steps > 0), fb * config.subpixel / jnp.maximum(steps, 1.0), 0.0)


def _neighbours(a: jax.Array) -> list[jax.Array]:
    """The 4-neighbours (left, right, up, down) of every pixel of ``a: [..., H, W]``, 0 outside."""
    pad = [(0, 0)] * (a.ndim - 2) + [(1, 1), (1, 1)]
    p = jnp.pad(a, pad)
    return [p[..., 1:-1, :-2], p[..., 1:-1, 2:], p[..., :-2, 1:-1], p[..., 2:, 1:-1]]


def _discontinuities(depth: jax.Array, jump: float) -> jax.Array:
    """[..., H, W] bool: a pixel with a return one of whose 4-neighbours differs by > jump * depth
    (a neighbour without return counts as a jump; the image border does not)."""
    H, W = depth.shape[-2:]
    inside = [jnp.ones((H, W), bool).at[:, 0].set(False), jnp.ones((H, W), bool).at[:, -1].set(False),
              jnp.ones((H, W), bool).at[0, :].set(False), jnp.ones((H, W), bool).at[-1, :].set(False)]
    edge = jnp.zeros(depth.shape, bool)
    for n, ok in zip(_neighbours(depth), inside, strict=True):
        edge |= ok & (jnp.abs(n - depth) > jump * depth)
    return edge & (depth > 0)


def _dilate(mask: jax.Array, radius: int) -> jax.Array:
    """``mask: [..., H, W]`` grown by ``radius`` px in the 4-neighbourhood sense, ``radius`` times."""
    for _ in range(max(radius, 0)):
        grown = mask
        for n in _neighbours(mask.astype(jnp.float32)):
            grown |= n > 0
        mask = grown
    return mask


def _cos_incidence(depth: jax.Array, intrinsics: Intrinsics) -> jax.Array:
    """[..., H, W] |cos| of the angle between the surface normal and the viewing ray, 1 where unknown.

    Normals are the cross product of tangents from neighbouring back-projected points: the central
    difference where both neighbours have a return, the one-sided one where one has, none where neither
    has. Exact on planes. Across a depth discontinuity the "surface" looks steep, so a silhouette pixel
    reads as grazing, which is also what the sensor does there.
    """
    rays = jnp.asarray(pixel_rays(intrinsics), depth.dtype)  # [H, W, 3], z = 1
    points = depth[..., None] * rays
    pad = [(0, 0)] * (depth.ndim - 2) + [(1, 1), (1, 1), (0, 0)]
    P = jnp.pad(points, pad)
    ok = [n > 0 for n in _neighbours(depth)]  # left, right, up, down

    def tangent(p_minus, p_plus, ok_minus, ok_plus):
        both = (ok_minus & ok_plus)[..., None]
        t = jnp.where(both, (p_plus - p_minus) / 2, 0.0)
        t = jnp.where((ok_plus & ~ok_minus)[..., None], p_plus - points, t)
        return jnp.where((ok_minus & ~ok_plus)[..., None], points - p_minus, t)

    t_u = tangent(P[..., 1:-1, :-2, :], P[..., 1:-1, 2:, :], ok[0], ok[1])
    t_v = tangent(P[..., :-2, 1:-1, :], P[..., 2:, 1:-1, :], ok[2], ok[3])
    normal = jnp.cross(t_u, t_v)
    n_norm = safe_norm(normal)
    cos = safe_div(jnp.abs(jnp.sum(normal * rays, axis=-1)), n_norm * safe_norm(rays))
    return jnp.where((n_norm > _TINY) & (depth > 0), jnp.clip(cos, 0.0, 1.0), 1.0)


def measure(key: jax.Array, depth: jax.Array, T_true: np.ndarray, intrinsics: Intrinsics, config: SensorConfig
            ) -> tuple[jax.Array, np.ndarray]:
    """What a sensor delivers for rendered frames: (depth [K, H, W] f32 m through ``apply_sensor``, T_wc [K, 4,
    4] the poses the pipeline is told: ``T_true`` (float64, exact) or, with ``pose_noise``, perturbed). One key
    for the frames of a scene, split into the depth's and the poses' (``World.measure``, ``SceneBank`` scenes:
    the same frames from the same key; ``measure_scenes`` for several scenes in one call). The key is split and
    the poses drawn on the host's CPU device, so that nothing here waits for work queued on an accelerator (a key
    made there is waited for once, to move it); the depth is measured where it lies, asynchronously."""
    key_depth, T_believed = _split_and_pose(key, T_true, config)
    if not isinstance(depth, jax.Array):
        depth = jnp.asarray(depth, jnp.float32)  # (onto the default device, or jax.default_device's)
    return apply_sensor(jax.device_put(key_depth, next(iter(depth.devices()))), depth, intrinsics, config), T_believed


def measure_scenes(keys: Sequence[jax.Array], depth: jax.Array, T_true: np.ndarray, intrinsics: Intrinsics,
                   config: SensorConfig) -> tuple[jax.Array, np.ndarray]:
    """``measure`` of S scenes at once: ``keys`` one a scene, ``depth: [S, K, H, W]`` m rendered, ``T_true: [S, K,
    4, 4]``. The same frames and poses as S calls of ``measure``, in one program and one transfer of the keys:
    (depth [S, K, H, W] f32 m, T_wc [S, K, 4, 4] float64)."""
    T_true = np.asarray(T_true, np.float64)
    if len(keys) != depth.shape[0] or T_true.shape[:2] != depth.shape[:2]:
        raise ValueError(f"measure_scenes: {len(keys)} keys, depth {tuple(depth.shape)} and T_true "
                         f"{T_true.shape} must agree on [S, K]")
    split = [_split_and_pose(k, T, config) for k, T in zip(keys, T_true, strict=True)]
    if not isinstance(depth, jax.Array):
        depth = jnp.asarray(depth, jnp.float32)
    with jax.default_device(devices.host_cpu()):
        key_depth = jnp.stack([k for k, _ in split])  # [S, ...] (stacked on the host's CPU, then moved once)
    key_depth = jax.device_put(key_depth, next(iter(depth.devices())))
    return _apply_sensor_scenes(key_depth, depth, intrinsics, config), np.stack([T for _, T in split])


@jax.jit
def _apply_sensor_scenes(keys: jax.Array, depth: jax.Array, intrinsics: Intrinsics, config: SensorConfig
                         ) -> jax.Array:
    """``apply_sensor`` of each scene's frames ``depth: [S, K, H, W]`` with its key ``keys: [S, ...]``, one scene
    after the other (``lax.map``: one scene's temporaries at a time, not S, e.g. 50 scenes of 100 frames at 640x480
    would need tens of GB at once under ``vmap``)."""
    return jax.lax.map(lambda kd: apply_sensor(kd[0], kd[1], intrinsics, config), (keys, depth))


def _split_and_pose(key: jax.Array, T_true: np.ndarray, config: SensorConfig) -> tuple[jax.Array, np.ndarray]:
    """(the depth's key on the host's CPU device, T_wc [K, 4, 4] float64 believed) of one scene's key."""
    host = devices.host_cpu()
    with jax.default_device(host):
        key_depth, key_pose = jax.random.split(jax.device_put(key, host))
        T_believed = np.asarray(T_true, np.float64)  # a pass through jax would round exact poses to float32
        if config.pose_noise:
            T_believed = np.asarray(perturb_poses(key_pose, T_true, config), dtype=np.float64)
    return key_depth, T_believed
