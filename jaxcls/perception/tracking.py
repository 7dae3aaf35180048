"""Frame-to-model tracking: each depth frame registered to the fused model before it is fused (KinectFusion's
tracking), and the robot's hand-eye error estimated online from the corrections.

A robot reports where its camera is; with a hand-eye calibration error the report is off by a fixed
transform in the camera frame, ~8-10 mm at the objects, in a different world direction for every view, and
fusing the frames at the reported poses blurs the TSDF (RESULTS.md, "Why PointNetFull is below the
policies"). ``track`` corrects the pose before ``observation.reconstruct`` fuses the frame:

1. **Prediction.** The reported pose ``T_rep`` corrected by the hand-eye estimate: ``E @ T_rep @ Y``
   (``HandEye``), the identity until frames have been registered.
2. **Registration** (``register``), point-to-plane Gauss-Newton on SE(3), coarse to fine over an image
   pyramid (every ``stride``-th pixel, ``levels`` levels, the finest ``finest_stride``):
   - *object pairs, projective data association*: each surface point q (normal n) of the fused model
     (``Observation.surface``, the TSDF's zero crossings) that faces the camera is projected into the new
     frame at the current pose estimate T; the pixel it lands on gives the frame's point p (camera frame);
     the residual is n . (T p - q). No nearest-neighbour search: the projection is the association.
     Pairs farther apart than ``max_distance`` (doubled per coarser level) or whose frame normal turns
     from n by more than ``max_normal_angle`` are dropped (occluders, the table under an object);
   - *table pairs*: frame pixels whose world point lies within ``table_band`` of the table plane with a
     vertical normal are held to the plane z = table height (residual z - h, normal e_z). The table is
     known geometry: it fixes height, roll and pitch of every frame, the first included, in the true
     world; the objects fix x, y and yaw relative to the model.
   - robust weights (Huber, ``huber`` m); the rotation is solved about the pairs' centroid (conditioning);
     the update is ``T <- exp(xi) T`` (xi in the world frame);
   - the prediction as a prior: a direction the pairs hardly constrain (a rotation the objects' walls see
     with a short lever arm) stays near it, the more so the more frames the hand-eye estimate has seen.
3. **The check** (``accept``): enough object pairs (count and share of the facing surface points that
   land on a return), RMS residual, and a correction no larger than ``max_rotation_deg`` /
   ``max_translation`` from the prediction. A refused frame is fused at the prediction (the reported pose
   until a hand-eye estimate exists) and counted (``Tracking.refused``, ``Status.REFUSED``).
4. **Hand-eye** (``HandEye``): every accepted pair (reported, corrected) is an observation of
   ``T_corrected = E @ T_reported @ Y``: Y is the camera-side error (the true camera is ``T_reported @ Y``
   when the fused model sits in the true world), E the model's offset from the true world in x, y and yaw
   (the first frame's error, which no later frame can see). Both are re-estimated by Gauss-Newton over the
   last ``window`` accepted frames after each one (``estimate_hand_eye``), with a weak prior towards the
   identity (one frame alone cannot tell E from Y).

Pure JAX with static shapes: ``track`` runs inside ``observe``'s jit, vmaps over episodes and scans over
frames. Poses are ``[4, 4]`` camera-to-world ``T_wc`` (OpenCV camera); lengths in metres.
"""

from __future__ import annotations

import dataclasses
import enum
import math

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from flax import struct

from jaxcls import geometry
from jaxcls.config import bounded, check_bounds
from jaxcls.geometry import Intrinsics
from jaxcls.math import normal_equations, normalize, safe_div
from jaxcls.perception import foreground

HIGHEST = jax.lax.Precision.HIGHEST


class TrackingMode(enum.StrEnum):
    """Where a frame is fused: at its ``reported`` pose (tracking off), or where ``frame_to_model``
    registration puts it."""

    reported = "reported"
    frame_to_model = "frame_to_model"


class Status(enum.IntEnum):
    """What ``track`` did with a frame (``Tracking.status``)."""

    REPORTED = 0  # not registered: tracking off (mode "reported"), or a first frame the table could not correct
    ACCEPTED = 1  # registered and fused at the corrected pose
    REFUSED = 2  # registration failed the check: fused at the predicted pose


@dataclasses.dataclass(frozen=True)
class TrackingConfig:
    """The ``perception.tracking`` block: frame-to-model registration before fusion. Lengths in metres."""

    mode: TrackingMode = TrackingMode.frame_to_model  # reported: every frame fused at its reported pose (off)
    levels: int = bounded(2, ge=1)  # image pyramid levels, coarse to fine
    finest_stride: int = bounded(2, ge=1)  # every n-th pixel at the finest level (x2 per coarser level)
    iterations: int = bounded(4, ge=1)  # Gauss-Newton steps per level
    max_distance: float = bounded(0.01, gt=0.0)  # pairs farther apart are dropped (finest level; x2 per level)
    max_normal_angle: float = bounded(45.0, gt=0.0, le=180.0)  # deg between frame and model normals
    huber: float = bounded(0.004, gt=0.0)  # robust weights: residuals beyond this count linearly
    table: bool = True  # table pixels held to the plane z = table height (height, roll, pitch)
    table_band: float = bounded(0.02, gt=0.0)  # frame points this close to the table plane may be table
    table_weight: float = bounded(1.0, ge=0.0)  # the table pairs' total weight relative to the object pairs'
    table_stride: int = bounded(8, ge=1)  # table pixels: every n-th pixel (a plane needs few)
    model_points: int = bounded(4096, ge=16)  # model surface points registered (evenly strided)
    # The prediction as a prior (sigmas of its error before any frame is registered; they shrink as
    # 1 / sqrt(1 + frames) as the hand-eye estimate gathers frames).
    prior_translation: float = bounded(0.005, gt=0.0)
    prior_rotation_deg: float = bounded(0.5, gt=0.0)
    # The check that accepts a registration.
    min_pairs: int = bounded(200, ge=1)  # object pairs at the finest level
    min_pair_share: float = bounded(0.3, ge=0.0, le=1.0)  # of facing model points landing on a return
    max_rms: float = bounded(0.005, gt=0.0)  # RMS point-to-plane residual of the object pairs
    max_rotation_deg: float = bounded(3.0, gt=0.0)  # largest correction from the prediction
    max_translation: float = bounded(0.03, gt=0.0)
    # Online hand-eye estimate from the accepted corrections.
    hand_eye: bool = True
    window: int = bounded(16, ge=1)  # accepted frames kept for the estimate
    hand_eye_iterations: int = bounded(4, ge=1)

    def __post_init__(self) -> None:
        check_bounds(self, "tracking.")

    @property
    def on(self) -> bool:
        return self.mode is TrackingMode.frame_to_model

    def strides(self) -> tuple[int, ...]:
        """Pixel strides of the pyramid, coarse to fine."""
        return tuple(self.finest_stride * 2 ** (self.levels - 1 - i) for i in range(self.levels))

    def distances(self) -> tuple[float, ...]:
        """Pair gates per level, coarse to fine, m."""
        return tuple(self.max_distance * 2 ** (self.levels - 1 - i) for i in range(self.levels))


# --------------------------------------------------------------------------- state


@struct.dataclass
class HandEye:
    """The running hand-eye estimate: ``T_corrected = world @ T_reported @ eye``.

    world: [4, 4] E, the fused model's frame in the reported world (x, y, yaw of the first frame's error);
    eye: [4, 4] Y, the camera-side correction (the true camera is ``T_reported @ Y``; the sensor model's
    ``T_reported = T_true @ dT`` gives Y = dT^-1); reported, corrected: [K, 4, 4] the last K accepted
    frames' poses (a ring buffer), filled: [K] bool; count: [] i32 accepted frames seen.
    """

    world: jax.Array
    eye: jax.Array
    reported: jax.Array
    corrected: jax.Array
    filled: jax.Array
    count: jax.Array

    @classmethod
    def identity(cls, window: int) -> HandEye:
        eye = jnp.eye(4, dtype=jnp.float32)
        buffer = jnp.tile(eye, (window, 1, 1))
        return cls(world=eye, eye=eye, reported=buffer, corrected=buffer, filled=jnp.zeros(window, bool),
                   count=jnp.zeros((), jnp.int32))

    def predict(self, T_reported: jax.Array) -> jax.Array:
        """[..., 4, 4] the poses ``T_reported: [..., 4, 4]`` corrected by the estimate: E @ T @ Y."""
        return _mm(_mm(self.world, T_reported), self.eye)

    def unpredict(self, T_model: jax.Array) -> jax.Array:
        """[..., 4, 4] the reported pose that ``predict`` maps to ``T_model`` (where to send the robot)."""
        return _mm(_mm(geometry.invert_rigid(self.world), T_model), geometry.invert_rigid(self.eye))


@struct.dataclass
class Tracking:
    """What tracking knows after the frames fused so far.

    pose: [4, 4] T_wc the last frame was fused at; predicted: [4, 4] its prediction (``HandEye.predict``
    of the reported pose); status: [] i32 the last frame's ``Status``; pairs: [] i32 its object pairs at
    the finest level; rms: [] f32 m their RMS point-to-plane residual; accepted, refused: [] i32 frames so
    far; hand_eye: the running ``HandEye`` estimate.
    """

    pose: jax.Array
    predicted: jax.Array
    status: jax.Array
    pairs: jax.Array
    rms: jax.Array
    accepted: jax.Array
    refused: jax.Array
    hand_eye: HandEye

    @classmethod
    def create(cls, config: TrackingConfig) -> Tracking:
        eye = jnp.eye(4, dtype=jnp.float32)
        zero = jnp.zeros((), jnp.int32)
        return cls(pose=eye, predicted=eye, status=zero, pairs=zero, rms=jnp.zeros((), jnp.float32),
                   accepted=zero, refused=zero, hand_eye=HandEye.identity(config.window))


@struct.dataclass
class Fit:
    """One registration's outcome. pose: [4, 4] the estimate; pairs: [] i32 object pairs (finest level);
    candidates: [] i32 facing model points that landed on a return; table: [] i32 table pairs; rms: [] f32 m
    object pairs' RMS residual."""

    pose: jax.Array
    pairs: jax.Array
    candidates: jax.Array
    table: jax.Array
    rms: jax.Array


# --------------------------------------------------------------------------- registration


def _mm(a: jax.Array, b: jax.Array) -> jax.Array:
    return jnp.matmul(a, b, precision=HIGHEST)


def _level_intrinsics(intrinsics: Intrinsics, stride: int) -> Intrinsics:
    """The camera of every ``stride``-th pixel: pixel (u', v') is the full image's (stride u', stride v')."""
    h, w = -(-intrinsics.height // stride), -(-intrinsics.width // stride)
    return Intrinsics(width=w, height=h, fx=intrinsics.fx / stride, fy=intrinsics.fy / stride,
                      cx=intrinsics.cx / stride, cy=intrinsics.cy / stride)


def vertex_normals(depth: jax.Array, intrinsics: Intrinsics, max_jump: float = 0.05
                   ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Camera-frame points and normals of a depth map: ([H, W, 3] points, [H, W, 3] unit normals facing the
    camera, [H, W] bool normal valid). A normal is the cross product of the central differences; valid where
    the pixel and its 4 neighbours have returns within ``max_jump`` x depth of each other."""
    rays = jnp.asarray(geometry.pixel_rays(intrinsics), jnp.float32)
    points = rays * depth[..., None]
    pad = jnp.pad(points, ((1, 1), (1, 1), (0, 0)))
    dpad = jnp.pad(depth, 1)
    du = pad[1:-1, 2:] - pad[1:-1, :-2]
    dv = pad[2:, 1:-1] - pad[:-2, 1:-1]
    n = jnp.cross(du, dv)
    n = jnp.where(jnp.sum(n * points, axis=-1, keepdims=True) > 0, -n, n)
    neighbours = [dpad[1:-1, 2:], dpad[1:-1, :-2], dpad[2:, 1:-1], dpad[:-2, 1:-1]]
    ok = depth > 0
    for d in neighbours:
        ok &= (d > 0) & (jnp.abs(d - depth) <= max_jump * depth)
    return points, normalize(n), ok


def _subsample(mask: jax.Array, size: int) -> tuple[jax.Array, jax.Array]:
    """([size] i32 indices, [size] bool) of at most ``size`` of the True entries of ``mask: [P]``, evenly strided."""
    slot, keep = foreground.strided_slots(jnp.cumsum(mask) - 1, jnp.sum(mask), size)
    keep &= mask
    target = jnp.where(keep, slot, size)  # out of bounds: dropped
    index = jnp.zeros(size, jnp.int32).at[target].set(jnp.arange(mask.shape[0], dtype=jnp.int32), mode="drop")
    ok = jnp.zeros(size, bool).at[target].set(True, mode="drop")
    return index, ok


def _object_pairs(T: jax.Array, q: jax.Array, n: jax.Array, qmask: jax.Array, points: jax.Array,
                  normals: jax.Array, nok: jax.Array, intrinsics: Intrinsics, gate: float, cos_gate: float):
    """Object pairs at pose estimate ``T``: model points q (normals n, mask [Q]) projected into the frame
    (projective data association). Returns (frame points in the world [Q, 3], residuals n . (T p - q) [Q],
    pair mask [Q], candidates [Q]: facing model points that landed on a return)."""
    R, t = T[:3, :3], T[:3, 3]
    H, W = intrinsics.height, intrinsics.width
    qc = geometry.rotate(R.T, q - t)  # R^T (q - t)
    nc = geometry.rotate(R.T, n)
    z = qc[:, 2]
    facing = qmask & (z > 1e-3) & (jnp.sum(nc * qc, axis=-1) < 0)
    inv_z = 1.0 / jnp.where(facing, z, 1.0)
    u, v = (jnp.round(c) for c in intrinsics.project(qc[:, 0], qc[:, 1], inv_z))
    inside = facing & (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
    pixel = jnp.where(inside, v * W + u, 0).astype(jnp.int32)
    p = points.reshape(-1, 3)[pixel]
    candidates = inside & (p[:, 2] > 0)
    pw = geometry.rotate(R, p) + t
    nw = geometry.rotate(R, normals.reshape(-1, 3)[pixel])
    diff = pw - q
    pair = (candidates & nok.reshape(-1)[pixel] & (jnp.sum(diff * diff, axis=-1) <= gate**2)
            & (jnp.sum(nw * n, axis=-1) >= cos_gate))
    return pw, jnp.sum(n * diff, axis=-1), pair, candidates


def _table_pairs(T: jax.Array, points: jax.Array, normals: jax.Array, nok: jax.Array, table_height: float,
                 band: float, cos_gate: float):
    """Table pairs at pose estimate ``T``: frame points [M, 3] (camera frame) within ``band`` of the plane
    z = table height with a vertical normal. Returns (world points [M, 3], residuals z - h [M], mask [M])."""
    R, t = T[:3, :3], T[:3, 3]
    tw = geometry.rotate(R, points) + t
    up = geometry.rotate(R, normals)[:, 2]  # world z of the normals
    r = tw[:, 2] - table_height
    return tw, r, nok & (points[:, 2] > 0) & (jnp.abs(r) <= band) & (up >= cos_gate)


def _solve(a: jax.Array, normal: jax.Array, r: jax.Array, w: jax.Array, T: jax.Array, T_prior: jax.Array,
           prior: jax.Array) -> jax.Array:
    """[4, 4] the world-frame update exp(xi) minimising sum w (r + J xi)^2 (J = [n, (a - c) x n], the rotation
    about the pairs' centroid c) plus the prior sum prior_i (d_i + xi_i)^2, d: how far T has moved from
    ``T_prior`` (translation at c, rotation), prior: [6] weights."""
    c = safe_div(jnp.sum(w[:, None] * a, axis=0), jnp.sum(w))
    J = jnp.concatenate([normal, jnp.cross(a - c, normal)], axis=-1)  # [Q, 6]: translation, rotation
    moved = _mm(T_prior, geometry.invert_rigid(T))  # where T_prior puts what T puts at c
    d = jnp.concatenate([c - (moved[:3, :3] @ c + moved[:3, 3]),
                         jaxlie.SO3.from_matrix(_mm(T[:3, :3], T_prior[:3, :3].T)).log()])
    Hm, g = normal_equations(J, w, r)
    Hm, g = Hm + jnp.diag(prior), g + prior * d
    damping = 1e-6 * jnp.trace(Hm) / 6.0 + 1e-12
    xi = -jnp.linalg.solve(Hm + damping * jnp.eye(6), g)
    xi = jnp.where(jnp.all(jnp.isfinite(xi)), xi, 0.0)
    Rw = jaxlie.SO3.exp(xi[3:]).as_matrix()
    return jnp.eye(4).at[:3, :3].set(Rw).at[:3, 3].set(c + xi[:3] - Rw @ c)


def register(depth: jax.Array, intrinsics: Intrinsics, T_init: jax.Array, surface_points: jax.Array,
             surface_normals: jax.Array, surface_mask: jax.Array, table_height: float, config: TrackingConfig,
             prior_frames: jax.Array | int = 0) -> Fit:
    """Register a depth frame to the fused model (and the table plane), from the pose ``T_init``.

    depth: [H, W] z-depth, m (0 = no return); T_init: [4, 4] T_wc; surface_*: the model's [P, 3] points,
    [P, 3] outward normals, [P] mask (``tsdf.Surface``), of which ``model_points`` evenly strided take part.
    Table pixels come from every ``table_stride``-th pixel. ``T_init`` is also a prior (``prior_translation``,
    ``prior_rotation_deg``), tighter by sqrt(1 + ``prior_frames``): the frames the hand-eye estimate has seen.
    Returns the ``Fit`` after the last level (not yet checked: ``accept``).
    """
    depth = jnp.asarray(depth, jnp.float32)
    depth = jnp.where(jnp.isfinite(depth) & (depth > 0), depth, 0.0)
    T = T_prior = jnp.asarray(T_init, jnp.float32)
    # The prior: the prediction's sigmas, shrinking as the hand-eye estimate gathers frames (1 / sqrt(1 + n)),
    # against residuals of ``huber`` m: a direction the pairs hardly see stays near the prediction.
    shrink = jnp.sqrt(1.0 + jnp.asarray(prior_frames, jnp.float32))
    sigma = jnp.asarray([config.prior_translation] * 3 + [math.radians(config.prior_rotation_deg)] * 3)
    prior = (config.huber * shrink / sigma) ** 2
    index, qmask = _subsample(surface_mask, config.model_points)
    q, n = surface_points[index], surface_normals[index]
    cos_gate = math.cos(math.radians(config.max_normal_angle))
    up = jnp.asarray([0.0, 0.0, 1.0])
    table_level = _level_intrinsics(intrinsics, config.table_stride)
    table_data = [x.reshape(-1, *x.shape[2:]) for x in vertex_normals(depth[::config.table_stride,
                                                                            ::config.table_stride], table_level)]

    def pairs(T, level, frame, gate):
        pw, r_obj, pair, candidates = _object_pairs(T, q, n, qmask, *frame, level, gate, cos_gate)
        tw, r_tab, table = _table_pairs(T, *table_data, table_height, config.table_band, cos_gate)
        table &= config.table
        n_obj, n_tab = jnp.sum(pair).astype(jnp.float32), jnp.sum(table).astype(jnp.float32)
        scale = jnp.where(n_obj > 0, config.table_weight * safe_div(n_obj, n_tab), 1.0)
        r = jnp.concatenate([r_obj, r_tab])
        w = jnp.minimum(1.0, config.huber / jnp.maximum(jnp.abs(r), 1e-9)) * jnp.concatenate([pair, table * scale])
        a = jnp.concatenate([pw, tw])
        normal = jnp.concatenate([n, jnp.broadcast_to(up, tw.shape)])
        return a, normal, r, w, pair, candidates, table

    for stride, gate in zip(config.strides(), config.distances(), strict=True):
        level = _level_intrinsics(intrinsics, stride)
        frame = vertex_normals(depth[::stride, ::stride], level)

        def step(T, _, level=level, frame=frame, gate=gate):
            a, normal, r, w, *_ = pairs(T, level, frame, gate)
            return _mm(_solve(a, normal, r, w, T, T_prior, prior), T), None

        T, _ = jax.lax.scan(step, T, None, length=config.iterations)
    _, _, r, _, pair, candidates, table = pairs(T, level, frame, gate)
    count = jnp.sum(pair)
    rms = jnp.sqrt(safe_div(jnp.sum(jnp.where(pair, r[:config.model_points] ** 2, 0.0)), count.astype(jnp.float32)))
    return Fit(pose=_orthonormal(T), pairs=count.astype(jnp.int32), candidates=jnp.sum(candidates).astype(jnp.int32),
               table=jnp.sum(table).astype(jnp.int32), rms=rms)


def accept(fit: Fit, T_init: jax.Array, config: TrackingConfig, first: jax.Array) -> jax.Array:
    """[] bool whether ``fit`` passes the check (``TrackingConfig``): on the first frame (no model) the
    table pairs alone, later enough object pairs with a small residual; a correction within bounds."""
    delta = jaxlie.SE3.from_matrix(_mm(geometry.invert_rigid(T_init), fit.pose)).log()
    small = ((jnp.linalg.norm(delta[:3]) <= config.max_translation)
             & (jnp.linalg.norm(delta[3:]) <= math.radians(config.max_rotation_deg)))
    objects = ((fit.pairs >= config.min_pairs) & (fit.rms <= config.max_rms)
               & (fit.pairs >= config.min_pair_share * fit.candidates))
    table = fit.table >= config.min_pairs
    return small & jnp.all(jnp.isfinite(fit.pose)) & jnp.where(first, table, objects)


def _orthonormal(T: jax.Array) -> jax.Array:
    """The nearest rigid transform (rotation re-orthonormalised through jaxlie)."""
    R = jaxlie.SO3.from_matrix(T[:3, :3]).normalize().as_matrix()
    return T.at[:3, :3].set(R).at[3].set(jnp.asarray([0.0, 0.0, 0.0, 1.0], T.dtype))


# --------------------------------------------------------------------------- hand-eye


# Residual scales of the hand-eye fit (a pose residual of 1 mm weighs as one of 0.1 deg) and its prior
# (the sensor model's sigmas, 3 mm and 0.3 deg, loosened: the prior only splits what one frame cannot tell).
_HE_SCALE = np.array([1e-3] * 3 + [math.radians(0.1)] * 3, np.float32)
_HE_PRIOR = np.array([0.01] * 3 + [math.radians(1.0)] * 3, np.float32)


def estimate_hand_eye(hand_eye: HandEye, iterations: int) -> HandEye:
    """E and Y of ``T_corrected = E @ T_reported @ Y`` over the buffered frames, by Gauss-Newton from the
    current estimate (12 parameters; a prior towards the identity on both)."""
    def residuals(x: jax.Array, world: jaxlie.SE3, eye: jaxlie.SE3) -> jax.Array:
        E = jaxlie.SE3.exp(x[:6]) @ world
        Y = eye @ jaxlie.SE3.exp(x[6:])
        rep = jaxlie.SE3.from_matrix(hand_eye.reported)
        cor = jaxlie.SE3.from_matrix(hand_eye.corrected)
        r = ((E @ rep @ Y).inverse() @ cor).log() / _HE_SCALE  # [K, 6]
        r = jnp.where(hand_eye.filled[:, None], r, 0.0).reshape(-1)
        prior = jnp.concatenate([E.log() / _HE_PRIOR, Y.log() / _HE_PRIOR])
        return jnp.concatenate([r, prior])

    def body(carry, _):
        world, eye = carry
        x0 = jnp.zeros(12)
        r = residuals(x0, world, eye)
        J = jax.jacfwd(residuals)(x0, world, eye)
        Hm = jnp.matmul(J.T, J, precision=HIGHEST) + 1e-9 * jnp.eye(12)
        x = -jnp.linalg.solve(Hm, jnp.matmul(J.T, r, precision=HIGHEST))
        x = jnp.where(jnp.all(jnp.isfinite(x)), x, 0.0)
        return (jaxlie.SE3.exp(x[:6]) @ world, eye @ jaxlie.SE3.exp(x[6:])), None

    (world, eye), _ = jax.lax.scan(body, (jaxlie.SE3.from_matrix(hand_eye.world), jaxlie.SE3.from_matrix(hand_eye.eye)),
                                   None, length=iterations)
    return hand_eye.replace(world=world.as_matrix(), eye=eye.as_matrix())


def observe_hand_eye(hand_eye: HandEye, T_reported: jax.Array, T_corrected: jax.Array, iterations: int) -> HandEye:
    """The estimate after one more accepted frame: the pair joins the ring buffer, then ``estimate_hand_eye``."""
    K = hand_eye.filled.shape[0]
    slot = hand_eye.count % K
    buffered = hand_eye.replace(reported=hand_eye.reported.at[slot].set(T_reported),
                                corrected=hand_eye.corrected.at[slot].set(T_corrected),
                                filled=hand_eye.filled.at[slot].set(True), count=hand_eye.count + 1)
    return estimate_hand_eye(buffered, iterations)


def pose_error(T: np.ndarray, reference: np.ndarray | None = None) -> tuple[float, float]:
    """(translation mm, rotation deg) of the rigid transform ``T`` (``reference^-1 @ T`` if given), on the host
    in float64 (the angle from the rotation vector: exact near 0, unlike the trace's arccos)."""
    from scipy.spatial.transform import Rotation

    T = np.asarray(T, np.float64)
    if reference is not None:
        T = np.linalg.inv(np.asarray(reference, np.float64)) @ T
    return float(np.linalg.norm(T[:3, 3]) * 1e3), float(np.degrees(Rotation.from_matrix(T[:3, :3]).magnitude()))


# --------------------------------------------------------------------------- the stage


def track(config: TrackingConfig, state: Tracking, depth: jax.Array, T_reported: jax.Array, intrinsics: Intrinsics,
          table_height: float, surface_points: jax.Array, surface_normals: jax.Array, surface_mask: jax.Array,
          first: jax.Array) -> Tracking:
    """The pose to fuse the frame at: the reported pose, predicted by the hand-eye estimate, registered to
    the model (and the table), checked. ``first``: [] bool no frame fused yet (the model is empty: the
    table alone can correct it). Returns the new ``Tracking`` (``pose`` is the one to fuse at)."""
    T_reported = jnp.asarray(T_reported, jnp.float32)
    if not config.on:
        return state.replace(pose=T_reported, predicted=T_reported, status=jnp.asarray(Status.REPORTED, jnp.int32))
    predicted = state.hand_eye.predict(T_reported)
    seen = jnp.minimum(state.hand_eye.count, config.window) if config.hand_eye else 0
    fit = register(depth, intrinsics, predicted, surface_points, surface_normals, surface_mask & ~first,
                   table_height, config, seen)
    ok = accept(fit, predicted, config, first)
    registered = ~first  # the first frame has no model: the table alone may correct it, else it stays reported
    status = jnp.where(ok, Status.ACCEPTED, jnp.where(registered, Status.REFUSED, Status.REPORTED))
    pose = jnp.where(ok, fit.pose, predicted)
    hand_eye = state.hand_eye
    if config.hand_eye:
        updated = observe_hand_eye(hand_eye, T_reported, pose, config.hand_eye_iterations)
        hand_eye = jax.tree.map(lambda new, old: jnp.where(ok, new, old), updated, hand_eye)
    return state.replace(pose=pose, predicted=predicted, status=status.astype(jnp.int32), pairs=fit.pairs,
                         rms=fit.rms, accepted=state.accepted + ok.astype(jnp.int32),
                         refused=state.refused + (registered & ~ok).astype(jnp.int32), hand_eye=hand_eye)
