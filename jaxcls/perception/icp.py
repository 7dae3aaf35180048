"""Point-to-plane ICP of a segment onto an object model, and the registration ratio (paper Eq. 2).

The model is the fixed side. ``model_target`` turns an ``ObjectModel`` into a ``Target`` once, on the host
(NumPy/SciPy): surface samples with normals and a closest-sample lookup on a regular grid over the model's
bounds plus the maximum correspondence distance (the ``candidates`` nearest samples of each cell's centre,
from a KD-tree, then a step over the best one's nearest samples), so that an iteration is a few gathers per
segment point rather than a nearest-neighbour search.

``icp(source, mask, target, T_init, config)`` registers one segment ([P, 3] world points and a mask) onto
one model and returns the model-to-world pose and rho. It is pure and jit-able; batch it with ``vmap``
(segments x candidate models x pose hypotheses are one call in ``refine``). Each iteration:

    p_i = T_mw x_i                                  segment points in the model frame
    q_i, n_i = closest model sample and its normal  (grid lookup; pairs farther than max_correspondence
                                                     are dropped)
    min over (w, t) of sum_i ((R(w) (p_i - c) + c + t - q_i) . n_i)^2    linearised: R(w) ~ I + [w]x
    T_mw <- [exp(w), c + t - exp(w) c] T_mw         (c: the paired points' centroid, for conditioning)

``dof="yaw"`` restricts w to the world z axis (objects stand upright on the table: translation + yaw, 4
degrees of freedom); ``dof="full"`` solves all 6. The same objective as Open3D's
``TransformationEstimationPointToPlane`` (source = the segment, target = the model's samples), so both
converge to the same pose; ``tests/test_icp.py`` checks that they do.

Degenerate segments (fewer than 3 points, all points on a line or one spot, NaN points masked out) return
the initial pose with rho = 0; nothing returns NaN.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from flax import struct
from scipy.spatial import cKDTree

from jaxcls import compile_cache
from jaxcls.config import bounded, check_bounds
from jaxcls.geometry import invert_rigid, rotate
from jaxcls.math import normal_equations, row_dots, safe_div
from jaxcls.perception.foreground import compact

if TYPE_CHECKING:  # perception reads models, it does not import the world
    from jaxcls.world.objects import ObjectModel

HIGHEST = jax.lax.Precision.HIGHEST


class Dof(enum.StrEnum):
    """What ICP solves for: ``yaw``, translation + yaw about world z (upright objects), or ``full`` 6-DoF."""

    yaw = "yaw"
    full = "full"


class Lookup(enum.StrEnum):
    """Closest-sample search: ``grid`` (a precomputed lookup, O(points) gathers) or ``brute`` (every
    sample, exact)."""

    grid = "grid"
    brute = "brute"

_HOP_NEIGHBOURS = 8  # samples looked at per step of the closest-sample walk
_MIN_SPREAD = 1e-8  # m^2: a segment whose second principal variance is below this is a line or a point


@dataclasses.dataclass(frozen=True)
class ICPConfig:
    """ICP and registration-ratio settings. Lengths in metres."""

    iterations: int = bounded(20, ge=1)  # Gauss-Newton steps (a fixed count under lax.scan)
    max_correspondence: float = bounded(0.02, gt=0.0)  # pairs farther apart are not used in a step
    inlier_distance: float = bounded(0.01, gt=0.0)  # rho's inlier threshold (Eq. 2)
    dof: Dof = Dof.yaw  # "yaw": translation + yaw about world z (upright objects); "full": 6-DoF
    tolerance: float = bounded(1e-5, ge=0.0)  # converged once a step moves less (rad and m)
    points: int = bounded(512, ge=1)  # segment points used (an even stride over the segment's slots)
    model_points: int = bounded(2048, ge=1)  # model surface samples (the first ones: they are random)
    grid_resolution: int = bounded(64, ge=2)  # closest-sample lookup cells per axis
    candidates: int = bounded(4, ge=1)  # samples kept per cell; the nearest of them to the point is used
    hops: int = bounded(1, ge=0)  # then steps over that sample's 8 nearest samples (0: the grid alone)
    neighbours: int = bounded(32, ge=8)  # nearest samples kept per sample (rho's model side reads them all)
    # Closest-sample search: "grid" (the lookup above, O(points) gathers) or "brute" (every sample, exact;
    # O(points x samples): for comparison, measured in BENCHMARKS.md on both backends).
    lookup: Lookup = Lookup.grid

    def __post_init__(self) -> None:
        check_bounds(self, "icp.")


class Target(struct.PyTreeNode):
    """Models ready to be registered onto (model frames, metres): L models stacked, and ``which`` of them
    this registration uses. ``model_target`` makes one (L = 1); ``stack`` makes a library; ``select``
    points at one model without copying it (under ``vmap`` over ``which`` every lookup gathers straight
    from the stacked arrays, never from a per-registration copy of a model's grid).

    points: [L, S, 3] f32 surface samples; normals: [L, S, 3] f32 unit outward normals; mask: [L, S] bool
    (False = padding); grid: [L, G^3, K] i16 the K nearest samples of each cell's centre, cells flattened
    x-major (models have fewer than 32768 samples); origin: [L, 3] f32 the grid's min corner; cell: [L, 3]
    f32 the cell's edge lengths; neighbours: [L, S, Kn] i16 each sample's nearest samples (itself first);
    which: [] i32 the model used.
    """

    points: jax.Array
    normals: jax.Array
    mask: jax.Array
    grid: jax.Array
    origin: jax.Array
    cell: jax.Array
    neighbours: jax.Array
    which: jax.Array
    resolution: int = struct.field(pytree_node=False)
    hops: int = struct.field(pytree_node=False, default=1)
    brute: bool = struct.field(pytree_node=False, default=False)  # ICPConfig.lookup == "brute"

    def select(self, which: jax.Array | int) -> Target:
        """The same stack, registering onto model ``which``."""
        return self.replace(which=jnp.asarray(which, jnp.int32))

    def samples(self) -> tuple[jax.Array, jax.Array, jax.Array]:
        """The used model's (points [S, 3], normals [S, 3], mask [S])."""
        return self.points[self.which], self.normals[self.which], self.mask[self.which]

    def _at(self, index: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        """(points, normals, mask) of the used model's samples ``index`` (any shape of i32)."""
        return self._rows(self.points, index), self._rows(self.normals, index), self._rows(self.mask, index)

    def _rows(self, table: jax.Array, index: jax.Array, columns: int | None = None) -> jax.Array:
        """``table[which, index, :columns]`` of a stacked ``table: [L, S, ...]`` (any shape of i32 ``index``),
        gathered through one flat index ``which * S + index``: under ``vmap`` a pair index (which, index) is a
        [..., 2] array XLA writes out before the gather (on a GPU, 126 MB for GR's 8 hop candidates at 512
        episodes). ``columns``: only the first ones of each row gathered (the table is not sliced first)."""
        L, S = table.shape[:2]
        if L * S >= 2**31:
            raise ValueError(f"icp: a model library table of {L} x {S} rows is too large for int32 indices")
        rows = table.reshape(L * S, *table.shape[2:])
        flat = self.which * S + index
        return rows[flat] if columns is None else rows[flat, :columns]


def stack(targets: Sequence[Target]) -> Target:
    """One ``Target`` on the device holding every model of ``targets`` (each from ``model_target``, with the same
    sample count and config; ``device=False`` spares a round trip), ``which`` = 0: stacked on the host and put on
    the device at once (no program compiled or loaded for it)."""
    host = [t.replace(which=np.asarray(t.which)[None]) for t in targets]
    leaves = jax.tree.map(lambda *a: np.concatenate([np.asarray(x) for x in a]), *host)
    return jax.device_put(leaves.replace(which=np.int32(0)))


class Registration(struct.PyTreeNode):
    """What ``icp`` returns for one segment-model pair.

    pose: [4, 4] f32 model-to-world; rho: [] f32 the registration ratio (Eq. 2); segment_fraction: [] f32
    |S_R| / |S|; model_fraction: [] f32 |O_R| / |O|; matched: [S] bool the model samples matched by a
    segment point within the inlier distance; rmse: [] f32 m, of the inlier distances; iterations: []
    i32 steps taken before convergence; valid: [] bool False for a degenerate segment.
    """

    pose: jax.Array
    rho: jax.Array
    segment_fraction: jax.Array
    model_fraction: jax.Array
    matched: jax.Array
    rmse: jax.Array
    iterations: jax.Array
    valid: jax.Array


def model_target(model: ObjectModel, config: ICPConfig = ICPConfig(), samples: int | None = None,
                 device: bool = True) -> Target:
    """The ``Target`` of ``model`` (host side, once per model): its first ``samples`` (default
    ``config.model_points``) surface samples and the closest-sample grid over its bounds grown by
    ``config.max_correspondence`` on every side. Put on the device in one transfer; ``device=False``: the same
    with NumPy arrays (for ``stack``)."""
    count = min(samples or config.model_points, len(model.surface_points))
    if count >= 2**15:
        raise ValueError(f"icp: {model.name}: at most 32767 model samples (got {count}); lower icp.model_points")
    points = np.asarray(model.surface_points[:count], np.float64)
    normals = np.asarray(model.surface_normals[:count], np.float32)
    low = points.min(axis=0) - config.max_correspondence
    high = points.max(axis=0) + config.max_correspondence
    G = config.grid_resolution
    cell = (high - low) / G
    axes = [low[d] + (np.arange(G) + 0.5) * cell[d] for d in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    def lookups() -> dict[str, np.ndarray]:
        tree = cKDTree(points)
        return {"index": tree.query(centres, k=min(config.candidates, count), workers=-1)[1].astype(np.int16),
                "neighbours": tree.query(points, k=min(config.neighbours + 1, count), workers=-1)[1].astype(np.int16)}

    key = b"".join([points.tobytes(), np.asarray([G, config.candidates, config.neighbours, count]).tobytes(),
                    low.tobytes(), high.tobytes()])
    found = compile_cache.cached_arrays("icp_targets", key, lookups)  # the same across runs: kept on disk
    index, neighbours = found["index"], found["neighbours"]
    target = Target(points=points[None].astype(np.float32), normals=normals[None], mask=np.ones((1, count), bool),
                    grid=np.asarray(index, np.int16).reshape(1, G**3, -1),
                    origin=low[None].astype(np.float32), cell=cell[None].astype(np.float32),
                    neighbours=np.asarray(neighbours, np.int16).reshape(1, count, -1),
                    which=np.int32(0), resolution=G, hops=config.hops, brute=config.lookup is Lookup.brute)
    return jax.device_put(target) if device else target


def closest(target: Target, x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Nearest model sample of each model-frame point ``x: [P, 3]``: (index [P] i32, distance [P] f32 m).

    The nearest of the point's grid cell's candidates, then ``target.hops`` greedy steps to a nearer
    sample among the current one's 8 nearest samples: exact where that walk reaches the true nearest
    sample (the candidates of a cell are the nearest of its centre, not of every point in it; the walk
    repairs that near the surface, where correspondences are kept). Points outside the grid take the
    nearest border cell, whose samples are farther than ``max_correspondence``. With ``target.brute``
    (``ICPConfig.lookup = "brute"``): the nearest of all samples, exact."""
    if target.brute:  # every sample: exact
        points, _, real = target.samples()
        d2 = jnp.where(real, jnp.sum((x[:, None, :] - points[None]) ** 2, axis=-1), jnp.inf)
        index = jnp.argmin(d2, axis=1)
        return index, jnp.sqrt(jnp.take_along_axis(d2, index[:, None], axis=1)[:, 0])
    G = target.resolution
    origin, size = target.origin[target.which], target.cell[target.which]
    ijk = jnp.clip(jnp.floor((x - origin) / size).astype(jnp.int32), 0, G - 1)
    cell = (ijk[:, 0] * G + ijk[:, 1]) * G + ijk[:, 2]
    index, d2 = _nearest_of(target, x, target._rows(target.grid, cell).astype(jnp.int32))
    for _ in range(target.hops):
        hop = target._rows(target.neighbours, index, _HOP_NEIGHBOURS).astype(jnp.int32)
        index, d2 = _nearest_of(target, x, hop)
    return index, jnp.sqrt(d2)


def _nearest_of(target: Target, x: jax.Array, candidates: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The nearest of ``candidates: [P, K]`` sample indices to each point: (index [P], squared distance [P])."""
    points, _, real = target._at(candidates)
    d2 = jnp.where(real, jnp.sum((points - x[:, None, :]) ** 2, axis=-1), jnp.inf)
    best = jnp.argmin(d2, axis=1)[:, None]
    return jnp.take_along_axis(candidates, best, axis=1)[:, 0], jnp.take_along_axis(d2, best, axis=1)[:, 0]


def apply_rigid(T: jax.Array, x: jax.Array) -> jax.Array:
    """Points ``x: [..., 3]`` moved by the rigid ``T: [4, 4]`` (``geometry.rotate``'s full float32 products)."""
    return rotate(T[:3, :3], x) + T[:3, 3]


def _spread(x: jax.Array, w: jax.Array) -> jax.Array:
    """Second-largest principal variance (m^2) of the points ``x: [P, 3]`` weighted by ``w: [P]``."""
    n = jnp.sum(w)
    mean = safe_div(jnp.sum(w[:, None] * x, axis=0), n)
    cov = safe_div(normal_equations(x - mean, w, jnp.zeros_like(w))[0], n)  # J^T W J of the centred points
    return jnp.linalg.eigvalsh(cov)[1]


def _step(T_mw: jax.Array, x: jax.Array, w0: jax.Array, target: Target, config: ICPConfig
          ) -> tuple[jax.Array, jax.Array]:
    """One Gauss-Newton step: (the increment [4, 4] applied on the left of ``T_mw``, identity if too few
    pairs constrain it; the number of points within the inlier distance at ``T_mw``)."""
    p = apply_rigid(T_mw, x)
    index, dist = closest(target, p)
    w = (w0 & (dist <= config.max_correspondence)).astype(p.dtype)
    inliers = jnp.sum(w0 & (dist <= config.inlier_distance))
    q, n, _ = target._at(index)
    count = jnp.sum(w)
    c = safe_div(jnp.sum(w[:, None] * p, axis=0), count)
    pc = p - c
    r = jnp.sum((p - q) * n, axis=-1)  # point-to-plane residuals
    cross = jnp.cross(pc, n)
    if config.dof is Dof.full:
        J = jnp.concatenate([cross, n], axis=-1)  # [P, 6]: d r / d (w, t)
    else:
        axis = T_mw[:3, 2]  # world z in the model frame: the only rotation allowed
        J = jnp.concatenate([(cross @ axis)[:, None], n], axis=-1)  # [P, 4]
    k = J.shape[1]
    A, g = normal_equations(J, w, r)
    b = -g
    damping = 1e-6 * jnp.trace(A) / k + 1e-12  # Levenberg: keeps unconstrained directions still
    delta = jnp.linalg.solve(A + damping * jnp.eye(k, dtype=A.dtype), b)
    delta = jnp.where((count >= k) & jnp.all(jnp.isfinite(delta)), delta, 0.0)
    omega = delta[:3] if config.dof is Dof.full else delta[0] * T_mw[:3, 2]
    t = delta[-3:]
    R = jaxlie.SO3.exp(omega).as_matrix()
    step = jnp.eye(4, dtype=T_mw.dtype).at[:3, :3].set(R).at[:3, 3].set(c + t - R @ c)
    return step, inliers


class Alignment(struct.PyTreeNode):
    """What ``align`` returns: pose [4, 4] f32 model-to-world; fitness [] f32 the fraction of the used
    points within the inlier distance at the pose the last step started from (Open3D's ``fitness``; the
    final pose's once converged); iterations [] i32 steps taken; valid [] bool False for a degenerate
    segment (then pose = T_init, fitness = 0)."""

    pose: jax.Array
    fitness: jax.Array
    iterations: jax.Array
    valid: jax.Array


class _Iterate(NamedTuple):
    """ICP's loop state: T_mw [4, 4] the world-to-model estimate, done [] bool (converged or invalid), steps
    [] i32 iterations made, inliers [] i32 of the last one."""

    T_mw: jax.Array
    done: jax.Array
    steps: jax.Array
    inliers: jax.Array


def align(source: jax.Array, mask: jax.Array, target: Target, T_init: jax.Array, config: ICPConfig = ICPConfig()
          ) -> Alignment:
    """The ICP alone, without rho's model side (``icp`` adds it): a cheap score for pruning hypotheses.
    Arguments as ``icp``."""
    x, mask = subsample(source, mask, config.points)
    valid = (jnp.sum(mask) >= 3) & (_spread(x, mask.astype(x.dtype)) >= _MIN_SPREAD)
    T_init = jnp.asarray(T_init, jnp.float32)

    def body(carry: _Iterate, _) -> tuple[_Iterate, None]:
        T_mw, done, steps, inliers = carry
        step, now = _step(T_mw, x, mask, target, config)
        moved = jnp.maximum(jnp.linalg.norm(jaxlie.SO3.from_matrix(step[:3, :3]).log()),
                            jnp.linalg.norm(step[:3, 3]))
        T_new = jnp.where(done, T_mw, jnp.einsum("ij,jk->ik", step, T_mw, precision=HIGHEST))
        T_new = _orthonormalise(T_new)
        inliers = jnp.where(done, inliers, now)
        return _Iterate(T_new, done | (moved < config.tolerance), steps + (~done).astype(jnp.int32), inliers), None

    start = _Iterate(invert_rigid(T_init), ~valid, jnp.int32(0), jnp.int32(0))
    (T_mw, _, steps, inliers), _ = jax.lax.scan(body, start, None, length=config.iterations)
    return Alignment(pose=jnp.where(valid, invert_rigid(T_mw), T_init), iterations=steps, valid=valid,
                     fitness=jnp.where(valid, safe_div(inliers, jnp.sum(mask)), 0.0))


def icp(source: jax.Array, mask: jax.Array, target: Target, T_init: jax.Array, config: ICPConfig = ICPConfig(),
        seen_from: jax.Array | None = None) -> Registration:
    """Register a segment onto a model by point-to-plane ICP.

    source: [P, 3] f32 world points (m); mask: [P] bool real points (NaN points count as masked); target:
    the model (``model_target``); T_init: [4, 4] initial model-to-world pose; seen_from: optional [C, 3]
    world camera positions that have looked at the scene (NaN rows = none), for the visibility-aware rho
    (see ``registration_ratio``). At most ``config.points`` of the real points are used (evenly strided).
    """
    whole, whole_mask = subsample(source, mask, source.shape[0])  # NaN points out; rho reads them all
    fit = align(source, mask, target, T_init, config)
    ratio = registration_ratio(whole, whole_mask & fit.valid, target, fit.pose, config.inlier_distance, seen_from)
    return Registration(pose=fit.pose, iterations=fit.iterations, valid=fit.valid, **ratio)


def registration_ratio(source: jax.Array, mask: jax.Array, target: Target, pose: jax.Array,
                       inlier_distance: float, seen_from: jax.Array | None = None, neighbours: int | None = None
                       ) -> dict[str, jax.Array]:
    """The registration ratio of Eq. 2 at model-to-world ``pose`` [4, 4]:

        rho = (|S_R| / |S|) * (|O_R| / |O|)

    S: the segment's points (``mask``); S_R: those within ``inlier_distance`` of the model (of their
    nearest sample); O: the model's samples; O_R: the samples within ``inlier_distance`` of some segment
    point (found among the nearest samples of each point's nearest sample, ``Target.neighbours``: exact
    while an inlier ball holds no more samples than that). The first factor is what Open3D calls
    ``fitness`` (inlier correspondences over source points); the second asks the model to be covered
    too, so a small model hidden inside a big segment does not score 1. Counting O_R from the model side
    keeps it independent of how many points the segment has (a segment of 1024 points can cover more of a
    2048-sample model than the 1024 samples that are some point's nearest).

    With ``seen_from`` ([C, 3] world camera positions; NaN rows ignored), O counts only the samples whose
    outward normal faces at least one of those cameras (the visibility-aware variant: the back of an
    object that was only seen from one side is unseen, not missing). Self-occlusion is not modelled.
    ``neighbours`` reads only that many of each sample's nearest (a cheaper, lower estimate of O_R).
    Returns rho, segment_fraction, model_fraction, matched ([S] bool: O_R), rmse (m, of S_R).
    """
    T_mw = invert_rigid(pose)
    p = apply_rigid(T_mw, jnp.where(mask[:, None], source, 0.0))
    index, dist = closest(target, p)
    inlier = mask & (dist <= inlier_distance)
    points, normals, considered = target.samples()
    S = points.shape[0]
    near = target._rows(target.neighbours, index, neighbours).astype(jnp.int32)  # [P, Kn]: around each nearest
    close = inlier[:, None] & (jnp.sum((target._at(near)[0] - p[:, None, :]) ** 2, -1) <= inlier_distance**2)
    matched = jnp.zeros(S, bool).at[jnp.where(close, near, S)].set(True, mode="drop")
    if seen_from is not None:
        cams = apply_rigid(T_mw, jnp.nan_to_num(seen_from))  # cameras in the model frame
        ok = jnp.all(jnp.isfinite(seen_from), axis=-1)
        # n . (cam - x) > 0 as n . cam > n . x: [S, C] (``row_dots``: a product on the CPU, where a batched
        # einsum over [C, S, 3] is ~2x slower under vmap; fused into the comparison on an accelerator).
        facing = row_dots(normals, cams) > jnp.sum(normals * points, axis=-1, keepdims=True)  # [S, C]
        considered = considered & jnp.any(facing & ok[None, :], axis=1)
    segment_fraction = safe_div(jnp.sum(inlier), jnp.sum(mask))
    model_fraction = safe_div(jnp.sum(matched & considered), jnp.sum(considered))
    rmse = jnp.sqrt(safe_div(jnp.sum(jnp.where(inlier, dist**2, 0.0)), jnp.sum(inlier)))
    return {"rho": segment_fraction * model_fraction, "segment_fraction": segment_fraction,
            "model_fraction": model_fraction, "matched": matched, "rmse": rmse}


def subsample(source: jax.Array, mask: jax.Array, count: int) -> tuple[jax.Array, jax.Array]:
    """([count or P, 3], mask) at most ``count`` of the real points of ``source: [P, 3]`` (``mask: [P]``),
    evenly strided (``foreground.compact``); NaN points are dropped, free slots are zeros."""
    mask = mask & jnp.all(jnp.isfinite(source), axis=-1)
    if source.shape[0] <= count:
        return jnp.where(mask[:, None], source, 0.0), mask
    return compact(jnp.where(mask[:, None], source, 0.0), mask, count)



def _orthonormalise(T: jax.Array) -> jax.Array:
    """Project the rotation block back onto SO(3) (float32 products drift) through its quaternion."""
    return T.at[:3, :3].set(jaxlie.SO3.from_matrix(T[:3, :3]).normalize().as_matrix())
