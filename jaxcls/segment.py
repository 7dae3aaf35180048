"""Foreground extraction and segmentation into exactly N object candidates (paper Sec. 3.1).

The paper isolates the foreground by truncating depth and removing the table plane, fuses it, cuts the
reconstruction to a cube of interest, clusters it with DBSCAN and forces N clusters with K-means on the
cluster centres. DBSCAN merges objects that touch, so regrouping clusters cannot recover them; the step
after DBSCAN here splits them with a watershed on the table plane. Objects stand upright with disjoint
footprints, so the points' footprint (their xy occupancy, closed, holes filled) is a union of convex-ish
blobs joined by narrow necks where objects touch. The watershed runs on a field that peaks at object
centres: the footprint's distance to empty space times Hough votes for the vertical axis each side-wall
point faces (a point with outward normal n votes for p - r n_xy over a range of radii r). Its basins are
merged by persistence (peak minus saddle, lowest first) until N remain; a basin with no saddle to a higher
one (a separate DBSCAN cluster) has the empty space around it as its saddle (field 0) and joins the nearest
centre: the paper's merge of cluster centres, which takes small fragments early and separate objects last.
With fewer than N basins the part with the largest sum of squares is split by 2-means (K-means).

Two implementations of the same algorithm:
- ``segment``: the reference path, scikit-learn DBSCAN + SciPy grid operations on the host (one episode).
- ``segment_jax``: the scale path's twin, jittable with static shapes and vmappable over episodes: DBSCAN's
  noise rule on a grid, hole filling by connected components (label propagation with hooking), an exact
  separable distance transform, at most ``max_basins`` basins, fixed-length merge and K-means loops.

Conventions (DESIGN.md): metres, world z up, table at z = ``table_height``; OpenCV camera, ``T_wc``
camera-to-world; depth z-depth with 0 = no return. Point sets are padded: ``points [P, 3]`` + ``mask [P]``;
segments ``[N, Ps, 3]`` + ``[N, Ps]``. Labels ``[P]`` i32 give each point's segment, -1 = not
foreground or noise.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxcls import geometry
from jaxcls.geometry import Intrinsics


@dataclasses.dataclass(frozen=True)
class SegmentConfig:
    """Foreground and segmentation settings (an OmegaConf structured config). Lengths in metres."""

    num_segments: int = 5  # N, the paper's number of objects on the table
    points_per_segment: int = 1024  # Ps, the static size of a segment (PointNet's input size)
    # DBSCAN (3D) drops noise; surface points are ~ one 4.7 mm voxel apart, 2 voxels bridge a missed one.
    dbscan_eps: float = 0.01
    dbscan_min_samples: int = 5
    table_height: float = 0.0
    table_eps: float = 0.01  # points with z <= table_height + table_eps are table (2 voxels of TSDF noise)
    max_depth: float = 1.5  # depth beyond this is background, m (views are 1 m from the scene centre)
    roi_center: tuple[float, float, float] = (0.0, 0.0, 0.25)  # cube of interest (scenes are centred on 0)
    roi_size: float = 0.6
    # Footprint grid on the table plane (objects stand upright with disjoint footprints).
    footprint_cell: float = 0.005
    closing_steps: int = 1  # fills gaps between surface points ~ one voxel apart (more bridges objects)
    # Centre votes: side-wall points (|n_xy| > vote_min_horizontal) vote along -n_xy at vote_radii radii
    # up to vote_max_radius (the largest object radius); votes are blurred by vote_sigma cells.
    vote_min_horizontal: float = 0.5
    vote_max_radius: float = 0.10
    vote_radii: int = 20
    vote_sigma: float = 1.0
    vote_exponent: float = 0.5  # field = distance to empty space * (votes / max votes) ** vote_exponent
    # K-means splits (fewer basins than N): points enter as (x, y, w z), so tall objects are not cut at
    # mid-height; at most kmeans_iters Lloyd rounds.
    kmeans_iters: int = 20
    kmeans_z_weight: float = 0.25
    # JAX twin only: static bounds.
    max_basins: int = 64  # basins kept (highest peaks); cells of the others join the nearest kept basin
    max_cc_iters: int = 64  # label-propagation rounds (hooking converges in about log of the diameter)


@struct.dataclass
class Segments:
    """N segments padded to Ps points each.

    points: [N, Ps, 3] f32 world positions, m (0 where ``mask`` is False).
    normals: [N, Ps, 3] f32 unit normals (0 where ``mask`` is False).
    mask: [N, Ps] bool, True for real points.
    labels: [P] i32 segment of each input point, -1 = not foreground / noise.
    """

    points: jax.Array
    normals: jax.Array
    mask: jax.Array
    labels: jax.Array


# ----------------------------------------------------------------------------------------------------
# Foreground
# ----------------------------------------------------------------------------------------------------


@functools.partial(jax.jit, static_argnames=("intrinsics", "config"))
def foreground_depth(depth: jax.Array, intrinsics: Intrinsics, T_wc: jax.Array, config: SegmentConfig) -> jax.Array:
    """Depth with background and table pixels set to 0 (no return), before fusion.

    depth: [H, W] z-depth, m (0, NaN, inf, negative = no return); T_wc: [4, 4] camera-to-world.
    Zeroes pixels beyond ``max_depth`` and pixels whose world point has z <= table_height + table_eps.
    Returns [H, W] f32, never NaN.
    """
    assert depth.shape == (intrinsics.height, intrinsics.width), f"depth must be [H, W], got {depth.shape}"
    depth = jnp.asarray(depth, jnp.float32)
    good = jnp.isfinite(depth) & (depth > 0) & (depth <= config.max_depth)
    depth = jnp.where(good, depth, 0.0)
    # World height of each pixel's point (only the third row of the back-projection: 3x less work).
    T_wc = jnp.asarray(T_wc, jnp.float32)
    rays = np.asarray(geometry.pixel_rays(intrinsics), np.float32)  # [H, W, 3]
    z = depth * jnp.einsum("hwj,j->hw", rays, T_wc[2, :3]) + T_wc[2, 3]
    return jnp.where(good & (z > config.table_height + config.table_eps), depth, 0.0)


def foreground_mask(points: jax.Array, mask: jax.Array, config: SegmentConfig) -> jax.Array:
    """[P] bool: ``mask`` and finite and above the table and inside the cube of interest.

    points: [P, 3] m; mask: [P] bool. Pure jnp, usable inside jit.
    """
    points = jnp.asarray(points)
    finite = jnp.all(jnp.isfinite(points), axis=-1)
    centre = jnp.asarray(config.roi_center, points.dtype)
    inside = jnp.all(jnp.abs(points - centre) <= 0.5 * config.roi_size, axis=-1)
    above = points[:, 2] > config.table_height + config.table_eps
    return jnp.asarray(mask) & finite & inside & above


@functools.partial(jax.jit, static_argnames=("intrinsics", "config", "max_points"))
def single_view_points(depth: jax.Array, intrinsics: Intrinsics, T_wc: jax.Array, config: SegmentConfig,
                       max_points: int) -> tuple[jax.Array, jax.Array]:
    """One frame's foreground cloud without fusion (the paper's PointNetSingle input).

    depth: [H, W] m; T_wc: [4, 4]. Returns (points [max_points, 3] m, mask [max_points] bool): the
    foreground pixels' world points, evenly strided when there are more than ``max_points``.
    """
    fg = foreground_depth(depth, intrinsics, T_wc, config)
    pts = geometry.backproject(fg, intrinsics, jnp.asarray(T_wc, jnp.float32)).reshape(-1, 3)
    valid = foreground_mask(pts, (fg > 0).reshape(-1), config)
    return _compact(pts, valid, max_points)


def _strided_slots(rank: jax.Array, count: jax.Array, size: int) -> tuple[jax.Array, jax.Array]:
    """Slot of each row among ``size`` slots, and whether it is kept: all rows when ``count <= size``, else
    ``size`` of them evenly strided in order. rank: [M] i32 rank of the row in its set; count: size of its
    set ([M] or scalar). Returns ([M] i32 slot, [M] bool keep: the first row of each slot)."""
    stride = jnp.maximum(count.astype(jnp.float32) / size, 1.0)
    slot = jnp.floor(rank.astype(jnp.float32) / stride).astype(jnp.int32)
    keep = (rank == jnp.ceil(slot.astype(jnp.float32) * stride).astype(jnp.int32)) & (slot < size)
    return slot, keep


def _compact(points: jax.Array, valid: jax.Array, size: int) -> tuple[jax.Array, jax.Array]:
    """([size, 3], [size]) the valid rows of ``points: [M, 3]``, evenly strided if more than ``size``."""
    slot, keep = _strided_slots(jnp.cumsum(valid) - 1, jnp.sum(valid), size)
    keep &= valid
    target = jnp.where(keep, slot, size)  # out of bounds: dropped
    out = jnp.zeros((size, 3), points.dtype).at[target].set(points, mode="drop")
    mask = jnp.zeros(size, bool).at[target].set(True, mode="drop")
    return out, mask


# ----------------------------------------------------------------------------------------------------
# Reference path: scikit-learn DBSCAN and K-means, SciPy grid labelling (host)
# ----------------------------------------------------------------------------------------------------


def _grid_size(config: SegmentConfig) -> int:
    return int(np.ceil(config.roi_size / config.footprint_cell))


def _cell_of(x: np.ndarray | jax.Array, config: SegmentConfig, xp=np) -> np.ndarray | jax.Array:
    """[M, 2] i32 footprint cell (i along x, j along y) of world points ``x: [M, 3]``, clipped to the grid."""
    origin = xp.asarray(config.roi_center[:2], x.dtype) - 0.5 * config.roi_size
    ij = xp.floor((x[:, :2] - origin) / config.footprint_cell).astype(xp.int32)
    return xp.clip(ij, 0, _grid_size(config) - 1)


def _morph_np(m: np.ndarray, op) -> np.ndarray:
    """3x3 square erosion (op = np.minimum) or dilation (np.maximum) of ``m: [G, G]`` bool, outside = False."""
    G = m.shape[0]
    p = np.pad(m, 1)
    out = p[1:-1, 1:-1].copy()
    for di in (0, 1, 2):
        for dj in (0, 1, 2):
            out = op(out, p[di:di + G, dj:dj + G])
    return out


def _gaussian_kernel(sigma: float) -> np.ndarray:
    """SciPy's ``gaussian_filter`` kernel (truncated at 4 sigma)."""
    radius = int(4.0 * sigma + 0.5)
    k = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    return k / k.sum()


def _vote_targets(x: np.ndarray | jax.Array, normals: np.ndarray | jax.Array, config: SegmentConfig, xp=np):
    """Where side-wall points vote for their object's axis: ([M, R, 3] points, [M] weights |n_xy|, 0 = no vote)."""
    nxy = normals[:, :2]
    h = xp.sqrt(xp.sum(nxy**2, axis=1))
    weight = xp.where(h > config.vote_min_horizontal, h, 0.0)
    u = nxy / xp.maximum(h, 1e-12)[:, None]
    radii = xp.asarray(np.linspace(config.footprint_cell, config.vote_max_radius, config.vote_radii), x.dtype)
    xy = x[:, None, :2] - radii[None, :, None] * u[:, None, :]
    return xp.concatenate([xy, xp.zeros_like(xy[..., :1])], axis=-1), weight


def footprint_field_reference(y: np.ndarray, normals: np.ndarray, config: SegmentConfig
                              ) -> tuple[np.ndarray, np.ndarray]:
    """(occupancy [G, G] bool, field [G, G] f64) of points ``y: [M, 3]`` with unit ``normals: [M, 3]``.

    Occupancy: the points' cells, closed by ``closing_steps`` 3x3 steps, holes filled. Field: distance to
    empty space (cells) times the normalised, blurred centre votes to the power ``vote_exponent``.
    """
    from scipy import ndimage

    G = _grid_size(config)
    ij = _cell_of(y, config)
    raw = np.zeros((G, G), bool)
    raw[ij[:, 0], ij[:, 1]] = True
    occ = raw
    for _ in range(config.closing_steps):
        occ = _morph_np(occ, np.maximum)
    for _ in range(config.closing_steps):
        occ = _morph_np(occ, np.minimum)
    occ = ndimage.binary_fill_holes(occ | raw)
    distance = ndimage.distance_transform_edt(occ)
    targets, weight = _vote_targets(y, normals, config)
    tij = _cell_of(targets.reshape(-1, 3), config)
    votes = np.zeros((G, G))
    np.add.at(votes, (tij[:, 0], tij[:, 1]), np.repeat(weight, config.vote_radii))
    kernel = _gaussian_kernel(config.vote_sigma)
    votes = ndimage.convolve1d(ndimage.convolve1d(votes * occ, kernel, axis=0, mode="reflect"), kernel, axis=1,
                               mode="reflect")
    votes = votes / max(votes.max(), 1e-12)
    return occ, distance * np.maximum(votes, 0.0) ** config.vote_exponent


def _basins_np(field: np.ndarray, occ: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Steepest-ascent basins of ``field`` over the occupied cells (8-neighbours, ties to the larger index).

    Returns ([G, G] i64 basin per cell, -1 off; [K] peak heights), basins numbered by their peak's index.
    """
    G = field.shape[0]
    index = np.arange(G * G).reshape(G, G)
    f = np.where(occ, field, -np.inf)
    fp, ip = np.pad(f, 1, constant_values=-np.inf), np.pad(index, 1, constant_values=-1)
    best, up = f.copy(), index.copy()
    for di in (0, 1, 2):
        for dj in (0, 1, 2):
            v, vi = fp[di:di + G, dj:dj + G], ip[di:di + G, dj:dj + G]
            better = (v > best) | ((v == best) & (vi > up))
            best, up = np.where(better, v, best), np.where(better, vi, up)
    up = up.ravel()
    for _ in range(_POINTER_JUMPS):
        up = up[up]
    root = np.where(occ.ravel(), up, -1)
    peaks, basin = np.unique(root[root >= 0], return_inverse=True)
    out = np.full(G * G, -1)
    out[root >= 0] = basin
    return out.reshape(G, G), field.ravel()[peaks]


_POINTER_JUMPS = 14  # 2^14 > 120^2: every steepest-ascent chain of the footprint grid reaches its peak
_PAIR_SHIFTS = ((0, 1), (1, 0), (1, 1), (1, -1))  # each 8-neighbour pair once


def _saddles_np(basin: np.ndarray, field: np.ndarray, K: int) -> np.ndarray:
    """[K, K] highest min(field) over adjacent cell pairs of two basins; -inf where they do not touch."""
    G = basin.shape[0]
    saddle = np.full((K, K), -np.inf)
    bp, fp = np.pad(basin, 1, constant_values=-1), np.pad(field, 1)
    for di, dj in _PAIR_SHIFTS:
        lb, fb = bp[1 + di:1 + di + G, 1 + dj:1 + dj + G], fp[1 + di:1 + di + G, 1 + dj:1 + dj + G]
        sel = (basin >= 0) & (lb >= 0) & (basin != lb)
        value = np.minimum(field, fb)[sel]
        np.maximum.at(saddle, (basin[sel], lb[sel]), value)
        np.maximum.at(saddle, (lb[sel], basin[sel]), value)
    return saddle


def _merge_step(xp, alive, peak, saddle, centre, size, group):
    """One persistence merge: the live basin with the lowest peak - saddle (to a higher live basin) joins
    that basin. A basin with no saddle to a higher one (a separate DBSCAN cluster) is separated from it by
    empty space, where the field is 0: its cost is its peak, and it joins the nearest higher basin (the
    paper's merge of cluster centres), so fragments go early and separate objects last.
    Shared by both paths (``xp`` = numpy or jax.numpy)."""
    K = peak.shape[0]
    ar = xp.arange(K)
    higher = alive[None, :] & (ar[None, :] != ar[:, None]) & (
        (peak[None, :] > peak[:, None]) | ((peak[None, :] == peak[:, None]) & (ar[None, :] < ar[:, None])))
    s = xp.where(higher, saddle, -xp.inf)
    up = xp.argmax(s, axis=1)
    top = xp.take_along_axis(s, up[:, None], axis=1)[:, 0]
    d2 = xp.where(higher, xp.sum((centre[:, None] - centre[None]) ** 2, axis=-1), xp.inf)
    near = xp.argmin(d2, axis=1)
    linked = top > -xp.inf
    cost = xp.where(linked, peak - top, peak)  # no saddle: the empty space between, where the field is 0
    cost = xp.where(alive & xp.any(higher, axis=1), cost, xp.inf)
    i = xp.argmin(cost)
    t = xp.where(linked[i], up[i], near[i])
    row = xp.maximum(saddle[t], saddle[i])
    row = xp.where(ar == t, -xp.inf, row)
    if xp is np:
        saddle = saddle.copy()
        saddle[t], saddle[:, t] = row, row
        centre, size, alive = centre.copy(), size.copy(), alive.copy()
        centre[t] = (centre[t] * size[t] + centre[i] * size[i]) / (size[t] + size[i])
        size[t] += size[i]
        alive[i] = False
    else:
        saddle = saddle.at[t].set(row).at[:, t].set(row)
        centre = centre.at[t].set((centre[t] * size[t] + centre[i] * size[i]) / (size[t] + size[i]))
        size = size.at[t].add(size[i])
        alive = alive.at[i].set(False)
    return alive, saddle, centre, size, xp.where(group == i, t, group)


def _basin_centres(basin: np.ndarray | jax.Array, K: int, xp=np):
    """([K, 2] mean cell coordinates, [K] cell counts) of the basins of ``basin: [G, G]`` (-1 = none)."""
    G = basin.shape[0]
    ii, jj = xp.meshgrid(xp.arange(G), xp.arange(G), indexing="ij")
    coords = xp.stack([ii.reshape(-1), jj.reshape(-1)], axis=-1)
    flat = basin.reshape(-1)
    valid = flat >= 0
    if xp is np:
        size = np.bincount(flat[valid], minlength=K).astype(float)
        total = np.stack([np.bincount(flat[valid], coords[valid, a], minlength=K) for a in range(2)], axis=-1)
    else:
        idx = jnp.where(valid, flat, K)  # an extra segment for the empty cells
        size = jax.ops.segment_sum(valid.astype(jnp.float32), idx, num_segments=K + 1)[:K]
        total = jax.ops.segment_sum(coords.astype(jnp.float32), idx, num_segments=K + 1)[:K]
    return total / xp.maximum(size, 1)[:, None], size


def _principal_split(x: np.ndarray) -> np.ndarray:
    """[2, 3] initial centres for splitting ``x: [M, 3]``: its mean -/+ one std along its main axis."""
    centre = x.mean(0)
    w, v = np.linalg.eigh(np.cov((x - centre).T, bias=True))
    step = np.sqrt(max(w[-1], 0.0)) * v[:, -1]
    return np.stack([centre - step, centre + step])


def cluster_reference(x: np.ndarray, normals: np.ndarray, config: SegmentConfig) -> np.ndarray:
    """[M] i64 partition of foreground points ``x: [M, 3]`` (unit ``normals``) into N segments, -1 = noise.

    DBSCAN drops noise; the footprint field's watershed basins are merged by persistence to N; every point
    takes its cell's basin; while there are fewer than N parts, the one with the largest sum of squares is
    split by 2-means.
    """
    from sklearn.cluster import DBSCAN, KMeans

    N, M = config.num_segments, len(x)
    labels = np.full(M, -1, np.int64)
    if M < N:
        return labels
    good = DBSCAN(eps=config.dbscan_eps, min_samples=config.dbscan_min_samples).fit_predict(x) >= 0
    y = x[good]
    if len(y) < N:
        return labels
    occ, field = footprint_field_reference(y, normals[good], config)
    basin, peak = _basins_np(field, occ)
    K = len(peak)
    state = (np.ones(K, bool), _saddles_np(basin, field, K), *_basin_centres(basin, K), np.arange(K))
    for _ in range(K - N):
        state = _merge_step(np, state[0], peak, *state[1:])
    group = state[-1]
    ij = _cell_of(y, config)
    _, part = np.unique(group[basin[ij[:, 0], ij[:, 1]]], return_inverse=True)
    ys = y * np.array([1.0, 1.0, config.kmeans_z_weight])
    while part.max() + 1 < N:
        sse = [((ys[part == j] - ys[part == j].mean(0)) ** 2).sum() for j in range(part.max() + 1)]
        sel = np.flatnonzero(part == int(np.argmax(sse)))
        if len(sel) < 2:
            break
        km = KMeans(n_clusters=2, init=_principal_split(ys[sel]), n_init=1, max_iter=config.kmeans_iters, tol=0.0)
        part[sel[km.fit(ys[sel]).labels_ == 1]] = part.max() + 1
    labels[good] = part
    return labels


@functools.partial(jax.jit, static_argnames=("n", "size"))
def pack_segments(points: jax.Array, normals: jax.Array, labels: jax.Array, n: int, size: int) -> Segments:
    """Gather each segment's points into a static ``[n, size]`` block (both paths share it).

    points, normals: [P, 3]; labels: [P] i32 in [-1, n). A segment with more than ``size`` points keeps
    ``size`` of them evenly strided in input order (surface points come in voxel order, so the subset is
    spread over the whole segment); deterministic, so both paths give the same blocks for the same labels.
    """
    labels = jnp.asarray(labels, jnp.int32)
    member = labels[:, None] == jnp.arange(n)  # [P, n]
    count = member.sum(0)
    rank = jnp.take_along_axis(jnp.cumsum(member, axis=0) - 1, jnp.clip(labels, 0, n - 1)[:, None], axis=1)[:, 0]
    slot, keep = _strided_slots(rank, count[jnp.clip(labels, 0, n - 1)], size)
    keep &= labels >= 0
    row, col = jnp.where(keep, labels, n), jnp.where(keep, slot, 0)
    pts = jnp.zeros((n, size, 3), jnp.float32).at[row, col].set(jnp.asarray(points, jnp.float32), mode="drop")
    nrm = jnp.zeros((n, size, 3), jnp.float32).at[row, col].set(jnp.asarray(normals, jnp.float32), mode="drop")
    msk = jnp.zeros((n, size), bool).at[row, col].set(True, mode="drop")
    return Segments(points=pts, normals=nrm, mask=msk, labels=labels)


def segment(points: np.ndarray | jax.Array, normals: np.ndarray | jax.Array, mask: np.ndarray | jax.Array,
            config: SegmentConfig) -> Segments:
    """Reference segmentation (host, scikit-learn) of a padded cloud into exactly N segments.

    points, normals: [P, 3] (m, unit); mask: [P] bool. Foreground is ``foreground_mask``; segments are
    ordered by centroid x then y and packed by ``pack_segments``. Fewer foreground points than N, or
    none: all masks empty, labels -1.
    """
    points = np.asarray(points, np.float32)
    fg = np.asarray(foreground_mask(points, mask, config))
    points = np.where(fg[:, None], points, 0.0).astype(np.float32)
    normals = np.where(fg[:, None], np.nan_to_num(np.asarray(normals, np.float32)), 0.0).astype(np.float32)
    labels = np.full(len(points), -1, np.int64)
    labels[fg] = cluster_reference(points[fg].astype(np.float64), normals[fg].astype(np.float64), config)
    labels = _order_segments(jnp.asarray(labels, jnp.int32), jnp.asarray(points), config.num_segments)
    return pack_segments(points, normals, labels, config.num_segments, config.points_per_segment)


# ----------------------------------------------------------------------------------------------------
# Scale path: the same algorithm in JAX, static shapes, jittable and vmappable over episodes
# ----------------------------------------------------------------------------------------------------


def _dense_points(x: jax.Array, valid: jax.Array, config: SegmentConfig) -> jax.Array:
    """[P] bool: DBSCAN's noise removal on a grid of eps/2 cells. A point is core when the 3x3x3 cells around
    its own (a block 1.5 eps wide, close to DBSCAN's eps ball) hold >= ``dbscan_min_samples`` valid points;
    it is kept when one of those cells holds a core point (DBSCAN's core and border points). Only the
    points' neighbourhoods are read (27 gathers each), never the whole grid."""
    cell = 0.5 * config.dbscan_eps
    G = int(np.ceil(config.roi_size / cell)) + 2  # one empty cell of margin on each side
    origin = jnp.asarray(config.roi_center, x.dtype) - 0.5 * config.roi_size - cell
    ijk = jnp.clip(jnp.floor((x - origin) / cell).astype(jnp.int32), 1, G - 2)
    flat = (ijk[:, 0] * G + ijk[:, 1]) * G + ijk[:, 2]
    offsets = jnp.asarray([(i * G + j) * G + k for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])
    around = flat[:, None] + offsets  # [P, 27]

    def neighbourhood_sum(flags):
        grid = jnp.zeros(G**3, jnp.int16).at[jnp.where(flags, flat, G**3)].add(1, mode="drop")
        return jnp.sum(grid[around], axis=1, dtype=jnp.int32)

    core = valid & (neighbourhood_sum(valid) >= config.dbscan_min_samples)
    return valid & (neighbourhood_sum(core) > 0)


def _shifted(a: jax.Array, di: int, dj: int, fill) -> jax.Array:
    """``a: [G, G, ...]`` moved so that out[i, j] = a[i + di, j + dj], ``fill`` outside."""
    G, k = a.shape[0], max(abs(di), abs(dj), 1)
    p = jnp.pad(a, [(k, k), (k, k)] + [(0, 0)] * (a.ndim - 2), constant_values=fill)
    return p[k + di:k + di + G, k + dj:k + dj + G]


_NEIGHBOURS = [(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)]
_CROSS = [(-1, 0), (1, 0), (0, -1), (0, 1)]


def _morph(m: jax.Array, dilate: bool) -> jax.Array:
    """3x3 square dilation or erosion of ``m: [G, G]`` bool, outside = False (as ``_morph_np``)."""
    out = m
    for di, dj in _NEIGHBOURS:
        out = (out | _shifted(m, di, dj, False)) if dilate else (out & _shifted(m, di, dj, False))
    return out


def _components(occ: jax.Array, max_iters: int, neighbours=_NEIGHBOURS) -> jax.Array:
    """[G, G] i32 connected component of each occupied cell (``neighbours``: 8 by default), named by its
    largest flat cell index; -1 off.

    Label propagation with hooking: each round every cell's representative is hooked (scatter-max) onto
    the largest representative in the cell's 3x3 neighbourhood, then the representatives' pointers are
    jumped; a few rounds (about the log of a component's diameter) until nothing changes.
    """
    G = occ.shape[0]
    cells = jnp.arange(G * G, dtype=jnp.int32)
    occ_flat = occ.reshape(-1)
    parent = cells

    def step(state):
        parent, _, i = state
        rep = jnp.where(occ, parent.reshape(G, G), -1)
        nb = rep
        for di, dj in neighbours:
            nb = jnp.maximum(nb, _shifted(rep, di, dj, -1))
        target = jnp.where(occ_flat, rep.reshape(-1), G * G)  # out of bounds: dropped
        new = parent.at[target].max(nb.reshape(-1), mode="drop")
        for _ in range(4):
            new = new[new]
        return new, jnp.any(new != parent), i + 1

    parent, _, _ = jax.lax.while_loop(lambda s: s[1] & (s[2] < max_iters), step, (parent, jnp.array(True), 0))
    return jnp.where(occ, parent.reshape(G, G), -1)


def _fill_holes(occ: jax.Array, max_iters: int) -> jax.Array:
    """``occ: [G, G]`` with its holes filled (SciPy's ``binary_fill_holes``): empty cells whose 4-connected
    empty component does not reach the grid's border."""
    G = occ.shape[0]
    empty = ~occ
    label = _components(empty, max_iters, _CROSS).reshape(-1)
    edge = (jnp.arange(G) == 0) | (jnp.arange(G) == G - 1)
    border = (edge[:, None] | edge[None, :]).reshape(-1)
    outside = jnp.zeros(G * G, bool).at[jnp.where(border & (label >= 0), label, G * G)].set(True, mode="drop")
    return occ | (empty & ~outside[jnp.maximum(label, 0)].reshape(G, G))


def _distance_transform(occ: jax.Array) -> jax.Array:
    """[G, G] f32 exact Euclidean distance (cells) of each occupied cell to the nearest empty one, 0 off.

    Separable: along each row the distance to the nearest empty cell (two running maxima), then for each
    cell the minimum over rows of that squared plus the squared row offset.
    """
    G = occ.shape[0]
    k = np.arange(G, dtype=np.float32)
    left = jax.lax.cummax(jnp.where(occ, -1e4, k[None, :]), axis=1)
    right = -jax.lax.cummax(jnp.where(occ, -1e4, -k[None, :]), axis=1, reverse=True)
    row = jnp.minimum(k[None, :] - left, right - k[None, :]) ** 2  # [i, j]
    offset2 = (k[:, None] - k[None, :]) ** 2
    return jnp.sqrt(jnp.min(row[None, :, :] + offset2[:, :, None], axis=1))


def _blur(a: jax.Array, sigma: float) -> jax.Array:
    """Separable Gaussian blur of ``a: [G, G]`` with SciPy's kernel and its 'reflect' border."""
    kernel = _gaussian_kernel(sigma)
    r = len(kernel) // 2
    for axis in (0, 1):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (r, r)
        p = jnp.pad(a, pad, mode="symmetric")
        a = sum(float(w) * jax.lax.slice_in_dim(p, t, t + a.shape[axis], axis=axis) for t, w in enumerate(kernel))
    return a


def _footprint_field(x: jax.Array, normals: jax.Array, kept: jax.Array, config: SegmentConfig
                     ) -> tuple[jax.Array, jax.Array]:
    """``footprint_field_reference`` in JAX: (occupancy [G, G] bool, field [G, G] f32)."""
    G = _grid_size(config)
    ij = _cell_of(x, config, xp=jnp)
    raw = jnp.zeros(G * G, bool).at[jnp.where(kept, ij[:, 0] * G + ij[:, 1], G * G)].set(True, mode="drop")
    raw = raw.reshape(G, G)
    occ = raw
    for _ in range(config.closing_steps):
        occ = _morph(occ, True)
    for _ in range(config.closing_steps):
        occ = _morph(occ, False)
    occ = _fill_holes(occ | raw, config.max_cc_iters)
    targets, weight = _vote_targets(x, normals, config, xp=jnp)
    tij = _cell_of(targets.reshape(-1, 3), config, xp=jnp)
    weight = jnp.repeat(jnp.where(kept, weight, 0.0), config.vote_radii)
    # Points that do not vote (tops, noise, padding) are sent out of bounds and dropped, rather than
    # adding 0 to one cell: on a GPU those additions all contend for that cell.
    target = jnp.where(weight > 0, tij[:, 0] * G + tij[:, 1], G * G)
    votes = jnp.zeros(G * G, x.dtype).at[target].add(weight, mode="drop").reshape(G, G)
    votes = _blur(votes * occ, config.vote_sigma)
    votes = votes / jnp.maximum(votes.max(), 1e-12)
    return occ, _distance_transform(occ) * jnp.maximum(votes, 0.0) ** config.vote_exponent


def _basins(field: jax.Array, occ: jax.Array, max_basins: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``_basins_np`` with at most ``max_basins`` basins (the highest peaks; the other cells join the
    nearest kept basin). Returns ([G, G] i32 basin, -1 off; [K] peak heights; [K] bool basin exists)."""
    G = field.shape[0]
    index = jnp.arange(G * G, dtype=jnp.int32).reshape(G, G)
    f = jnp.where(occ, field, -jnp.inf)
    best, up = f, index
    for di, dj in _NEIGHBOURS:
        v, vi = _shifted(f, di, dj, -jnp.inf), _shifted(index, di, dj, -1)
        better = (v > best) | ((v == best) & (vi > up))
        best, up = jnp.where(better, v, best), jnp.where(better, vi, up)
    up = up.reshape(-1)
    for _ in range(_POINTER_JUMPS):
        up = up[up]
    is_peak = occ.reshape(-1) & (up == index.reshape(-1))
    height, peak = jax.lax.top_k(jnp.where(is_peak, field.reshape(-1), -jnp.inf), max_basins)
    exists = height > -jnp.inf
    peak = jnp.sort(jnp.where(exists, peak, G * G))  # number basins by their peak's index, as SciPy's path
    exists = peak < G * G
    name = jnp.full(G * G + 1, -1, jnp.int32).at[peak].set(jnp.where(exists, jnp.arange(max_basins), -1))[:-1]
    basin = jnp.where(occ.reshape(-1), name[up], -1).reshape(G, G)
    orphan = occ & (basin < 0)
    basin = jax.lax.cond(jnp.any(orphan), lambda b: jnp.where(orphan, _nearest_seed(b), b), lambda b: b, basin)
    return basin, jnp.where(exists, field.reshape(-1)[jnp.minimum(peak, G * G - 1)], -jnp.inf), exists


def _saddles(basin: jax.Array, field: jax.Array, K: int) -> jax.Array:
    """``_saddles_np`` in JAX: [K, K] f32."""
    saddle = jnp.full(K * K, -jnp.inf, field.dtype)
    for di, dj in _PAIR_SHIFTS:
        lb, fb = _shifted(basin, di, dj, -1), _shifted(field, di, dj, 0.0)
        sel = ((basin >= 0) & (lb >= 0) & (basin != lb)).reshape(-1)
        value = jnp.minimum(field, fb).reshape(-1)
        a, b = basin.reshape(-1), lb.reshape(-1)
        saddle = saddle.at[jnp.where(sel, a * K + b, K * K)].max(value, mode="drop")
        saddle = saddle.at[jnp.where(sel, b * K + a, K * K)].max(value, mode="drop")
    return saddle.reshape(K, K)


def _nearest_seed(seeds: jax.Array) -> jax.Array:
    """[G, G] i32 value of the nearest seed cell (Euclidean, in cells) of every cell; seeds are the cells
    of ``seeds: [G, G]`` that are >= 0; -1 everywhere when there is none.

    Jump flooding: every cell keeps the nearest of the seeds its 8 neighbours at distance k hold, for
    k = G/2, ..., 2, 1, 1 (the last pass repairs the rare misses of the halving passes).
    """
    G = seeds.shape[0]
    ii, jj = jnp.meshgrid(jnp.arange(G), jnp.arange(G), indexing="ij")
    seed = jnp.where(seeds >= 0, ii * G + jj, -1)

    def dist2(s):
        return jnp.where(s >= 0, (ii - s // G) ** 2 + (jj - s % G) ** 2, 4 * G * G)

    steps = [1 << e for e in reversed(range(int(np.ceil(np.log2(G)))))] + [1]
    for k in steps:
        best, d = seed, dist2(seed)
        for di, dj in _NEIGHBOURS:
            cand = _shifted(seed, di * k, dj * k, -1)
            dc = dist2(cand)
            better = (dc < d) | ((dc == d) & (cand >= 0) & (cand < best))
            best, d = jnp.where(better, cand, best), jnp.where(better, dc, d)
        seed = best
    return jnp.where(seed >= 0, seeds.reshape(-1)[jnp.maximum(seed, 0)], -1)


def _kmeans(x: jax.Array, weight: jax.Array, init: jax.Array, iters: int) -> tuple[jax.Array, jax.Array]:
    """Lloyd's K-means of ``x: [M, D]`` with ``weight: [M]`` (0 = absent), from ``init: [K, D]``, for at most
    ``iters`` rounds, stopping when no label changes (scikit-learn's rule with ``tol=0``). A centre that
    loses all its points stays where it is. Returns (labels [M] i32, centres [K, D])."""
    K = init.shape[0]

    def assign(c):
        return jnp.argmin(jnp.sum((x[:, None, :] - c[None]) ** 2, axis=-1), axis=1).astype(jnp.int32)

    def update(label, c):
        total = jax.ops.segment_sum(weight, label, num_segments=K)
        sums = jax.ops.segment_sum(x * weight[:, None], label, num_segments=K)
        return jnp.where(total[:, None] > 0, sums / jnp.maximum(total, 1e-12)[:, None], c)

    def body(state):
        label, c, _, i = state
        c = update(label, c)
        new = assign(c)
        return new, c, jnp.any((new != label) & (weight > 0)), i + 1

    label = assign(init)
    label, centres, _, _ = jax.lax.while_loop(lambda s: s[2] & (s[3] < iters), body,
                                              (label, init, jnp.array(True), 0))
    return label, centres


_SPLIT_SAMPLE = 4096  # points a 2-means split fits its centres on


def _split_until_n(part: jax.Array, y: jax.Array, kept: jax.Array, config: SegmentConfig) -> jax.Array:
    """Split the part with the largest sum of squares by 2-means along its main axis until there are N."""
    N = config.num_segments
    ys = y * jnp.asarray([1.0, 1.0, config.kmeans_z_weight], y.dtype)
    w = kept.astype(y.dtype)

    def body(_, part):
        n = jnp.max(jnp.where(kept, part, -1)) + 1
        count = jax.ops.segment_sum(w, part, num_segments=N)
        mean = jax.ops.segment_sum(ys * w[:, None], part, num_segments=N) / jnp.maximum(count, 1)[:, None]
        sse = jax.ops.segment_sum(w * jnp.sum((ys - mean[part]) ** 2, axis=1), part, num_segments=N)
        g = jnp.argmax(jnp.where(count > 0, sse, -jnp.inf))
        sel = kept & (part == g)
        ws = sel.astype(y.dtype)
        centre = mean[g]
        d = (ys - centre) * ws[:, None]
        cov = d.T @ d / jnp.maximum(count[g], 1)
        evals, evecs = jnp.linalg.eigh(cov)
        step = jnp.sqrt(jnp.maximum(evals[-1], 0.0)) * evecs[:, -1]
        # Centres from an evenly strided subset of the part (static size), then every point to the nearer.
        sub, sub_mask = _compact(ys, sel, _SPLIT_SAMPLE)
        _, c = _kmeans(sub, sub_mask.astype(y.dtype), jnp.stack([centre - step, centre + step]),
                       config.kmeans_iters)
        half = jnp.sum((ys - c[1]) ** 2, axis=1) < jnp.sum((ys - c[0]) ** 2, axis=1)
        return jnp.where((count[g] >= 2) & sel & half, n, part)

    def needed(state):  # a while loop, not a cond: under vmap it stops when no episode needs a split
        part, i = state
        return (jnp.max(jnp.where(kept, part, -1)) + 1 < N) & (i < N - 1)

    return jax.lax.while_loop(needed, lambda s: (body(s[1], s[0]), s[1] + 1), (part, 0))[0]


def cluster_jax(x: jax.Array, normals: jax.Array, valid: jax.Array, config: SegmentConfig) -> jax.Array:
    """[P] i32 partition of the valid points ``x: [P, 3]`` (unit ``normals``) into N segments, -1 = invalid
    or noise: the JAX twin of ``cluster_reference``."""
    N, K = config.num_segments, config.max_basins
    kept = _dense_points(x, valid, config)
    occ, field = _footprint_field(x, normals, kept, config)
    basin, peak, exists = _basins(field, occ, K)
    centre, size = _basin_centres(basin, K, xp=jnp)

    state = (exists, _saddles(basin, field, K), centre, size, jnp.arange(K))
    group = jax.lax.while_loop(lambda s: jnp.sum(s[0]) > N, lambda s: _merge_step(jnp, s[0], peak, *s[1:]),
                               state)[-1]
    ij = _cell_of(x, config, xp=jnp)
    part = group[jnp.maximum(basin[ij[:, 0], ij[:, 1]], 0)]
    present = jnp.zeros(K, bool).at[part].max(kept)
    part = (jnp.cumsum(present) - 1)[part].astype(jnp.int32)
    part = _split_until_n(part, x, kept, config)
    enough = jnp.sum(kept) >= N
    return jnp.where(kept & enough, part, -1).astype(jnp.int32)


def _order_segments(labels: jax.Array, x: jax.Array, n: int) -> jax.Array:
    """Relabel segments by centroid x then y, empty ones last, so that the order is deterministic (both
    paths)."""
    onehot = jax.nn.one_hot(labels, n, dtype=x.dtype)
    count = onehot.sum(0)
    mean = (onehot.T @ x[:, :2]) / jnp.maximum(count, 1)[:, None]
    order = jnp.lexsort((mean[:, 1], mean[:, 0], count == 0))
    remap = jnp.zeros(n, jnp.int32).at[order].set(jnp.arange(n, dtype=jnp.int32))
    return jnp.where(labels >= 0, remap[jnp.maximum(labels, 0)], -1)


@functools.partial(jax.jit, static_argnames=("config",))
def segment_jax(points: jax.Array, normals: jax.Array, mask: jax.Array, config: SegmentConfig) -> Segments:
    """Scale-path segmentation, the twin of ``segment``: jittable, vmappable over episodes.

    points, normals: [P, 3] (m, unit); mask: [P] bool. Same contract as ``segment``; the partition agrees
    with it (adjusted Rand index, tested on rendered scenes).
    """
    points = jnp.asarray(points, jnp.float32)
    fg = foreground_mask(points, mask, config)
    x = jnp.where(fg[:, None], points, 0.0)
    normals = jnp.where(fg[:, None], jnp.nan_to_num(jnp.asarray(normals, jnp.float32)), 0.0)
    labels = _order_segments(cluster_jax(x, normals, fg, config), x, config.num_segments)
    return pack_segments(x, normals, labels, config.num_segments, config.points_per_segment)
