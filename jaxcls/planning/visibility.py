"""How many pixels of each object a candidate view would see (paper Eq. 5), from the segments' aligned
model cuboids, for every candidate view in one jitted call.

Each live segment is replaced by the bounding cuboid of its aligned model (8 corners in the model frame,
posed by its model-to-world transform). For a candidate camera ``T_wc`` the image (at ``scale`` of the
sensor's resolution: counting needs no more) is painted three ways:

- ``"paper"`` (hard, the paper's): the cuboid's corners are projected, the convex hull of the projection is
  filled, and whole segments are painted near to far (ordered by the depth of their cuboid's centre), so a
  nearer segment's hull hides a farther one's pixels;
- ``"exact"`` (hard): every pixel's ray is intersected with every cuboid (slab test) and the nearest hit owns
  the pixel: a per-pixel z-buffer of the cuboid faces;
- ``"no_occlusion"``: each hull counted alone (the paper's VisNoOccl).

``soft_counts`` is the differentiable twin of ``"paper"``: a pixel's coverage by a segment is a sigmoid of its
signed distance (pixels) to the hull's edges over ``edge_temperature``, and a nearer segment hides a farther
one by a soft depth order, a two-way softmax of their depths with ``depth_temperature`` (m); as both
temperatures go to 0 it tends to the hard count. Corners behind the camera are clipped at the near plane
(the cuboid is cut by it, the cut's points join the hull), never wrapped through infinity.

Shapes: corners [N, 8, 3] m (model frame), poses [N, 4, 4] model-to-world, live [N] bool, T_wc [V, 4, 4];
counts [V, N] f32 pixels (0 for dead segments).
"""

from __future__ import annotations

import dataclasses
import enum

import jax
import jax.numpy as jnp

from jaxcls.config import bounded, check_bounds
from jaxcls.geometry import Intrinsics, invert_rigid, pixel_rays
from jaxcls.math import safe_div, safe_norm

HIGHEST = jax.lax.Precision.HIGHEST


class Mode(enum.StrEnum):
    """How cuboids hide each other (see the module docstring)."""

    paper = "paper"
    exact = "exact"
    no_occlusion = "no_occlusion"


NEAR = 0.01  # m: the near plane cuboids are clipped at
# The 12 edges of a cuboid whose corner k has bits (x, y, z) = (k >> 2 & 1, k >> 1 & 1, k & 1).
EDGES = tuple((a, a | bit) for bit in (1, 2, 4) for a in range(8) if not a & bit)
HULL_EDGES = 16  # hull edges kept per segment (a clipped cuboid's silhouette has at most 10 vertices)


@dataclasses.dataclass(frozen=True)
class VisibilityConfig:
    """Resolution and temperatures of the visibility count."""

    scale: float = bounded(0.25, gt=0.0, le=1.0)  # of the sensor's resolution (0.25: 160 x 120 for 640 x 480)
    mode: Mode = Mode.paper
    edge_temperature: float = bounded(0.5, gt=0.0)  # pixels: soft coverage's sigmoid width
    depth_temperature: float = bounded(0.02, gt=0.0)  # m: soft depth ordering's softmax temperature

    def __post_init__(self) -> None:
        check_bounds(self, "visibility.")


def scaled(intrinsics: Intrinsics, scale: float) -> Intrinsics:
    """The same camera at ``scale`` of its resolution (same field of view; pixel centres at integers)."""
    width, height = max(1, round(intrinsics.width * scale)), max(1, round(intrinsics.height * scale))
    sx, sy = width / intrinsics.width, height / intrinsics.height
    return Intrinsics(width=width, height=height, fx=intrinsics.fx * sx, fy=intrinsics.fy * sy,
                      cx=(intrinsics.cx + 0.5) * sx - 0.5, cy=(intrinsics.cy + 0.5) * sy - 0.5)


def _pixels(intrinsics: Intrinsics) -> jax.Array:
    """[H * W, 2] pixel centres (u, v)."""
    v, u = jnp.meshgrid(jnp.arange(intrinsics.height, dtype=jnp.float32),
                        jnp.arange(intrinsics.width, dtype=jnp.float32), indexing="ij")
    return jnp.stack([u.reshape(-1), v.reshape(-1)], axis=-1)


def _camera_corners(corners: jax.Array, poses: jax.Array, T_wc: jax.Array) -> jax.Array:
    """[N, 8, 3] the cuboids' corners in the camera frame of ``T_wc`` [4, 4]."""
    T_cm = jnp.einsum("ij,njk->nik", invert_rigid(T_wc), poses, precision=HIGHEST)
    return jnp.einsum("nij,nkj->nki", T_cm[:, :3, :3], corners, precision=HIGHEST) + T_cm[:, None, :3, 3]


def _hull(points: jax.Array, valid: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The convex hull of 2D ``points: [K, 2]`` (``valid: [K]``) as up to ``HULL_EDGES`` directed edges:
    (start [E, 2], direction [E, 2], kept [E] bool), counter-clockwise in (u, v) with v down, so a point is
    inside when it lies on the same side of every kept edge. Edge i -> j is on the hull when every valid
    point lies on its inner side (static shapes: all K^2 pairs are tested)."""
    K = points.shape[0]
    d = points[None, :, :] - points[:, None, :]  # [i, j]: j - i
    rel = points[None, None, :, :] - points[:, None, None, :]  # [i, j, k]: k - i
    cross = d[..., 0:1] * rel[..., 1] - d[..., 1:2] * rel[..., 0]  # [i, j, k]
    length = jnp.linalg.norm(d, axis=-1)
    scale = jnp.maximum(jnp.max(jnp.where(valid, jnp.abs(points).max(-1), 0.0)), 1.0)
    tol = 1e-6 * scale * scale
    inner = jnp.all((cross >= -tol) | ~valid[None, None, :], axis=-1)
    edge = inner & valid[:, None] & valid[None, :] & (length > 1e-9 * scale) & ~jnp.eye(K, dtype=bool)
    flat = edge.reshape(-1)
    order = jnp.argsort(~flat, stable=True)[:HULL_EDGES]
    i, j = order // K, order % K
    return points[i], points[j] - points[i], flat[order]


def _projected_hull(cam: jax.Array, intrinsics: Intrinsics) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """The hull of one cuboid's projection (camera-frame corners ``cam: [8, 3]``), clipped at the near
    plane: its edges (``_hull``) and whether anything of it is in front of the camera."""
    z = cam[:, 2]
    a, b = jnp.array([e[0] for e in EDGES]), jnp.array([e[1] for e in EDGES])
    za, zb = z[a], z[b]
    crosses = (za - NEAR) * (zb - NEAR) < 0
    t = safe_div(NEAR - za, zb - za)
    cut = cam[a] + t[:, None] * (cam[b] - cam[a])  # [12, 3] where edges cross the near plane
    pts = jnp.concatenate([cam, cut], axis=0)
    valid = jnp.concatenate([z >= NEAR, crosses])
    zs = jnp.where(valid, pts[:, 2], 1.0)
    uv = jnp.stack(intrinsics.project(pts[:, 0], pts[:, 1], 1.0 / zs), -1)
    start, direction, kept = _hull(jnp.where(valid[:, None], uv, 0.0), valid)
    return start, direction, kept, jnp.sum(valid) >= 3


def _signed_distance(pixels: jax.Array, start: jax.Array, direction: jax.Array, kept: jax.Array) -> jax.Array:
    """[P] pixels: the distance of each pixel inside the hull to its nearest edge (negative outside).

    Each kept edge is a line n . x + c = 0 with its unit normal n pointing inwards."""
    length = safe_norm(direction)
    normal = jnp.stack([-direction[:, 1], direction[:, 0]], axis=-1) / jnp.where(length > 0, length, 1.0)[:, None]
    offset = jnp.where(kept & (length > 0), -jnp.sum(normal * start, axis=-1), jnp.inf)
    distance = jnp.full(pixels.shape[0], jnp.inf, pixels.dtype)
    for e in range(start.shape[0]):  # unrolled: a running minimum, no [P, E] array in memory
        distance = jnp.minimum(distance, pixels[:, 0] * normal[e, 0] + pixels[:, 1] * normal[e, 1] + offset[e])
    return distance


def _segment_depth(cam: jax.Array) -> jax.Array:
    """The depth (m, camera z) of a cuboid's centre: the paper's near-to-far order of whole segments."""
    return jnp.mean(cam[:, 2])


def _slab_depth(rays: jax.Array, corners: jax.Array, pose_cm: jax.Array) -> jax.Array:
    """[P] m: the distance along each camera ray ``rays: [P, 3]`` (unit z component scale: z = 1) to the
    cuboid (model-frame ``corners`` [8, 3], model-to-camera ``pose_cm`` [4, 4]); inf where it misses."""
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    R, t = pose_cm[:3, :3], pose_cm[:3, 3]
    origin = -R.T @ t  # the camera centre in the model frame
    direction = rays @ R  # [P, 3] ray directions in the model frame (R^T d)
    inv = safe_div(1.0, direction)
    parallel = jnp.abs(direction) < 1e-12
    t0, t1 = (lo - origin) * inv, (hi - origin) * inv
    near = jnp.where(parallel, -jnp.inf, jnp.minimum(t0, t1))
    far = jnp.where(parallel, jnp.inf, jnp.maximum(t0, t1))
    inside_slab = ~parallel | ((origin >= lo) & (origin <= hi))
    t_in, t_out = jnp.max(near, axis=1), jnp.min(far, axis=1)
    hit = jnp.all(inside_slab, axis=1) & (t_in <= t_out) & (t_out > NEAR)
    return jnp.where(hit, jnp.maximum(t_in, NEAR), jnp.inf)


def _counts_one_view(corners: jax.Array, poses: jax.Array, live: jax.Array, T_wc: jax.Array, intrinsics: Intrinsics,
                     mode: Mode) -> jax.Array:
    if mode is Mode.exact:
        rays = jnp.asarray(pixel_rays(intrinsics).reshape(-1, 3), jnp.float32)  # z = 1: t is the z-depth
        T_cm = jnp.einsum("ij,njk->nik", invert_rigid(T_wc), poses, precision=HIGHEST)
        depth = jax.vmap(lambda m, T: _slab_depth(rays, m, T))(corners, T_cm)  # [N, P]
        depth = jnp.where(live[:, None], depth, jnp.inf)
        owner = jnp.argmin(depth, axis=0)
        seen = jnp.isfinite(jnp.min(depth, axis=0))
        owned = (owner[None, :] == jnp.arange(corners.shape[0])[:, None]) & seen[None]
        return jnp.sum(owned, axis=1).astype(jnp.float32)
    cam = _camera_corners(corners, poses, T_wc)
    start, direction, kept, front = jax.vmap(lambda c: _projected_hull(c, intrinsics))(cam)
    lower, upper = jax.vmap(lambda s, d, k: _row_spans(s, d, k, intrinsics.height))(start, direction, kept)
    u = jnp.arange(intrinsics.width, dtype=jnp.float32)
    inside = (u >= lower[..., None]) & (u <= upper[..., None])  # [N, H, W]
    inside = inside & (live & front)[:, None, None]
    if mode is Mode.no_occlusion:
        return jnp.sum(inside, axis=(1, 2)).astype(jnp.float32)
    order = jnp.argsort(jax.vmap(_segment_depth)(cam), stable=True)  # near to far (ties: lower index first)
    free = jnp.ones(inside.shape[1:], bool)
    painted = []
    for k in range(corners.shape[0]):  # paint whole segments near to far through the z-buffer
        mine = inside[order[k]] & free
        painted.append(jnp.sum(mine))
        free = free & ~inside[order[k]]
    return jnp.zeros(corners.shape[0], jnp.float32).at[order].set(jnp.stack(painted).astype(jnp.float32))


def _row_spans(start: jax.Array, direction: jax.Array, kept: jax.Array, height: int
               ) -> tuple[jax.Array, jax.Array]:
    """The hull's extent along each pixel row: (lower [H], upper [H]) in u, empty where lower > upper.

    Edge e keeps the pixels with d_u (v - s_v) - d_v (u - s_u) >= 0, a bound on u for d_v != 0 (an upper
    one for d_v > 0, a lower one for d_v < 0) and a condition on the row alone for d_v = 0."""
    v = jnp.arange(height, dtype=jnp.float32)[:, None]
    du, dv = direction[None, :, 0], direction[None, :, 1]
    su, sv = start[None, :, 0], start[None, :, 1]
    rhs = du * (v - sv) + dv * su  # constraint: dv * u <= rhs
    flat = jnp.abs(dv) <= 1e-9
    bound = rhs / jnp.where(flat, 1.0, dv)
    upper = jnp.min(jnp.where(kept & ~flat & (dv > 0), bound, jnp.inf), axis=1)
    lower = jnp.max(jnp.where(kept & ~flat & (dv < 0), bound, -jnp.inf), axis=1)
    row_ok = jnp.all(~(kept & flat) | (du * (v - sv) >= 0), axis=1)
    return jnp.where(row_ok, lower, jnp.inf), jnp.where(row_ok, upper, -jnp.inf)


def counts(corners: jax.Array, poses: jax.Array, live: jax.Array, T_wc: jax.Array, intrinsics: Intrinsics,
           config: VisibilityConfig = VisibilityConfig()) -> jax.Array:
    """[V, N] f32: visible pixels of each segment at each candidate view (Eq. 5's terms), at
    ``config.scale`` of the sensor's resolution, by ``config.mode`` (see the module docstring)."""
    small = scaled(intrinsics, config.scale)
    return jax.vmap(lambda T: _counts_one_view(corners, poses, live, T, small, config.mode))(jnp.asarray(T_wc))


def soft_counts(corners: jax.Array, poses: jax.Array, live: jax.Array, T_wc: jax.Array, intrinsics: Intrinsics,
                config: VisibilityConfig = VisibilityConfig()) -> jax.Array:
    """[V, N] f32: the differentiable count (soft coverage, softmax depth order; see the module docstring),
    tending to ``counts`` in ``"paper"`` mode as the temperatures go to 0."""
    small = scaled(intrinsics, config.scale)
    pixels = _pixels(small)

    def one_view(T):
        cam = _camera_corners(corners, poses, T)
        start, direction, kept, front = jax.vmap(lambda c: _projected_hull(c, small))(cam)
        distance = jax.vmap(lambda s, d, k: _signed_distance(pixels, s, d, k))(start, direction, kept)
        cover = jax.nn.sigmoid(jnp.clip(distance, -1e4, 1e4) / config.edge_temperature)
        cover = cover * (live & front)[:, None]
        depth = jax.vmap(_segment_depth)(cam)
        # Soft z-buffer: segment k hides j where it covers the pixel and is nearer, softly: a two-way
        # softmax of their depths, sigmoid((d_j - d_k) / T). Its limit is the hard near-to-far painting
        # whatever the order in which the two temperatures go to 0.
        in_front = jax.nn.sigmoid((depth[:, None] - depth[None, :]) / config.depth_temperature)  # [j, k]
        in_front = in_front * (1.0 - jnp.eye(depth.shape[0]))
        hidden = in_front[:, :, None] * cover[None, :, :]  # [j, k, P]
        return jnp.sum(cover * jnp.prod(1.0 - hidden, axis=1), axis=1)

    return jax.vmap(one_view)(jnp.asarray(T_wc))



counts_jit = jax.jit(counts, static_argnames=("intrinsics", "config"))
soft_counts_jit = jax.jit(soft_counts, static_argnames=("intrinsics", "config"))
