"""Foreground extraction and segmentation into exactly N object candidates (paper Sec. 3.1).

The paper isolates the foreground by truncating depth and removing the table plane, fuses it, cuts the
reconstruction to a cube of interest, clusters it with DBSCAN and forces N clusters with K-means on the
cluster centres. DBSCAN merges objects that touch, so regrouping centres alone cannot recover them; here
the step after DBSCAN also splits: each large cluster owns K-means centres, the part with the largest
sum of squared distances is split along its principal axis until there are N, and a K-means restricted
to each cluster's own centres settles the partition. Small clusters (fragments) own no centre and join
the nearest one, which is the paper's merge by K-means on centres.

Two implementations of the same algorithm:
- ``segment``: the reference path, scikit-learn DBSCAN + K-means on the host (one episode, CPU).
- ``segment_jax``: the scale path's twin, jittable with static shapes: DBSCAN's connectivity is replaced
  by connected components of an occupancy grid (label propagation with pointer jumping in a
  ``lax.while_loop``), the splits and K-means run for a fixed number of iterations.

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
    # Footprint grid: objects stand upright with disjoint footprints, so the table-plane occupancy of the
    # points separates them; eroding it by up to ``max_erosion`` cells cuts the necks where objects touch.
    footprint_cell: float = 0.005
    closing_steps: int = 1  # fills holes between surface points ~ one voxel apart (more bridges gaps)
    max_erosion: int = 6
    min_core_cells: int = 6  # a smaller eroded component is a fragment, not an object
    # K-means: on core centres (weighted by size) when there are more cores than N (the paper's merge);
    # 2-means splits of the part with the largest sum of squares when there are fewer. Points enter the
    # splits as (x, y, w z): a tall object must not be cut at mid-height.
    kmeans_iters: int = 20
    kmeans_z_weight: float = 0.25
    # JAX twin only: static bounds.
    max_cores: int = 16  # the largest cores considered
    max_cc_iters: int = 64  # label-propagation rounds (each pointer-jumps, so ~log of the grid's diameter)


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
    z = geometry.backproject(depth, intrinsics, jnp.asarray(T_wc, jnp.float32))[..., 2]
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


def _compact(points: jax.Array, valid: jax.Array, size: int) -> tuple[jax.Array, jax.Array]:
    """([size, 3], [size]) the valid rows of ``points: [M, 3]``, evenly strided if more than ``size``."""
    count = jnp.sum(valid)
    rank = jnp.cumsum(valid) - 1  # rank of each valid row
    stride = jnp.maximum(count.astype(jnp.float32) / size, 1.0)
    slot = jnp.floor(rank.astype(jnp.float32) / stride).astype(jnp.int32)
    # Keep the first row of each slot: rank == ceil(slot * stride).
    keep = valid & (rank == jnp.ceil(slot.astype(jnp.float32) * stride).astype(jnp.int32)) & (slot < size)
    target = jnp.where(keep, slot, size)
    out = jnp.zeros((size + 1, 3), points.dtype).at[target].set(points)[:size]
    mask = jnp.zeros(size + 1, bool).at[target].set(keep)[:size]
    return jnp.where(mask[:, None], out, 0.0), mask


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


def _cell_centres(config: SegmentConfig) -> np.ndarray:
    """[G, G, 2] world xy of the footprint cell centres."""
    G = _grid_size(config)
    steps = (np.arange(G) + 0.5) * config.footprint_cell - 0.5 * config.roi_size
    cx, cy = config.roi_center[0] + steps, config.roi_center[1] + steps
    return np.stack(np.meshgrid(cx, cy, indexing="ij"), axis=-1)


def _morph_np(m: np.ndarray, op) -> np.ndarray:
    """3x3 square erosion (op = np.minimum) or dilation (np.maximum) of ``m: [G, G]`` bool, outside = False."""
    G = m.shape[0]
    p = np.pad(m, 1)
    out = p[1:-1, 1:-1].copy()
    for di in (0, 1, 2):
        for dj in (0, 1, 2):
            out = op(out, p[di:di + G, dj:dj + G])
    return out


def footprint_cores_reference(x: np.ndarray, config: SegmentConfig) -> np.ndarray:
    """Object cores of points ``x: [M, 3]`` from their footprint occupancy (host reference).

    The occupancy, closed by ``closing_steps`` 3x3 steps, is eroded 0, 1, ... ``max_erosion`` times; the
    first erosion with N components of >= ``min_core_cells`` cells is kept (else the first with the most):
    touching objects separate under erosion. Returns [G, G] i64 core index per cell, -1 = none; cores by
    size, largest first, ties by raster order; at most ``max_cores``.
    """
    from scipy import ndimage

    G, N = _grid_size(config), config.num_segments
    occ = np.zeros((G, G), bool)
    ij = _cell_of(x, config)
    occ[ij[:, 0], ij[:, 1]] = True
    for _ in range(config.closing_steps):
        occ = _morph_np(occ, np.maximum)
    for _ in range(config.closing_steps):
        occ = _morph_np(occ, np.minimum)
    best = None
    for _ in range(config.max_erosion + 1):
        lab, n = ndimage.label(occ, structure=np.ones((3, 3)))
        sizes = np.bincount(lab.ravel(), minlength=n + 1)[1:]
        count = min(int((sizes >= config.min_core_cells).sum()), N)
        if best is None or count > best[0]:
            best = (count, lab, sizes)
        if count >= N:
            break
        occ = _morph_np(occ, np.minimum)
    _, lab, sizes = best
    keep = np.flatnonzero(sizes >= config.min_core_cells)
    keep = keep[np.argsort(-sizes[keep], kind="stable")][: config.max_cores]  # label order = raster order
    index = np.full(len(sizes) + 1, -1, np.int64)
    index[keep + 1] = np.arange(len(keep))
    return index[lab]


def _principal_split(x: np.ndarray) -> np.ndarray:
    """[2, 3] initial centres for splitting ``x: [M, 3]``: its mean -/+ one std along its main axis."""
    centre = x.mean(0)
    w, v = np.linalg.eigh(np.cov((x - centre).T, bias=True))
    step = np.sqrt(max(w[-1], 0.0)) * v[:, -1]
    return np.stack([centre - step, centre + step])


def cluster_reference(x: np.ndarray, config: SegmentConfig) -> np.ndarray:
    """[M] i64 partition of foreground points ``x: [M, 3]`` into N segments (-1 = DBSCAN noise).

    DBSCAN drops noise; footprint cores seed the objects (K-means on core centres merges them when there
    are more than N); every point joins the group of its cell's nearest core cell; while there are fewer
    than N groups, the one with the largest sum of squares is split by 2-means.
    """
    from scipy import ndimage
    from sklearn.cluster import DBSCAN, KMeans

    N, M = config.num_segments, len(x)
    labels = np.full(M, -1, np.int64)
    if M < N:
        return labels
    good = DBSCAN(eps=config.dbscan_eps, min_samples=config.dbscan_min_samples).fit_predict(x) >= 0
    y = x[good]
    if len(y) < N:
        return labels
    cores = footprint_cores_reference(y, config)
    C = int(cores.max()) + 1
    part = np.zeros(len(y), np.int64)
    if C > 0:
        centres = _cell_centres(config)
        flat = cores.ravel()
        sizes = np.bincount(flat[flat >= 0], minlength=C).astype(float)
        core_xy = np.stack([np.bincount(flat[flat >= 0], centres.reshape(-1, 2)[flat >= 0, a], minlength=C)
                            for a in range(2)], axis=-1) / sizes[:, None]
        group = np.arange(C)
        if C > N:  # the paper's K-means on cluster centres
            km = KMeans(n_clusters=N, init=core_xy[:N], n_init=1, max_iter=config.kmeans_iters, tol=0.0)
            group = km.fit(core_xy, sample_weight=sizes).labels_
        _, nearest = ndimage.distance_transform_edt(cores < 0, return_indices=True)
        cell_group = group[cores[nearest[0], nearest[1]]]
        ij = _cell_of(y, config)
        part = cell_group[ij[:, 0], ij[:, 1]]
        _, part = np.unique(part, return_inverse=True)
    # Fewer groups than N: split the part with the largest sum of squares, along its main axis.
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


def _order_segments(labels: np.ndarray, x: np.ndarray, n: int) -> np.ndarray:
    """Relabel segments by centroid x then y (empty segments last), so that the order is deterministic."""
    keys = []
    for j in range(n):
        sel = labels == j
        keys.append((0, *x[sel, :2].mean(0)) if sel.any() else (1, 0.0, 0.0))
    order = sorted(range(n), key=lambda j: keys[j])
    remap = np.full(n + 1, -1, np.int64)
    remap[np.asarray(order)] = np.arange(n)
    return remap[labels]


def segment(points: np.ndarray | jax.Array, normals: np.ndarray | jax.Array, mask: np.ndarray | jax.Array,
            config: SegmentConfig, seed: int = 0) -> Segments:
    """Reference segmentation (host, scikit-learn) of a padded cloud into exactly N segments.

    points, normals: [P, 3] (m, unit); mask: [P] bool. Foreground is ``foreground_mask``; segments are
    ordered by centroid x then y; a segment with more than Ps points keeps a seeded random subset.
    Fewer foreground points than N, or none: all masks empty, labels -1.
    """
    N, size = config.num_segments, config.points_per_segment
    points = np.asarray(points, np.float32)
    fg = np.asarray(foreground_mask(points, mask, config))
    points = np.where(fg[:, None], points, 0.0).astype(np.float32)
    normals = np.where(fg[:, None], np.nan_to_num(np.asarray(normals, np.float32)), 0.0).astype(np.float32)
    labels = np.full(len(points), -1, np.int64)
    labels[fg] = cluster_reference(points[fg].astype(np.float64), config)
    labels = _order_segments(labels, points, N)
    rng = np.random.default_rng(seed)
    pts, nrm, msk = np.zeros((N, size, 3), np.float32), np.zeros((N, size, 3), np.float32), np.zeros((N, size), bool)
    for j in range(N):
        sel = np.flatnonzero(labels == j)
        if len(sel) > size:
            sel = np.sort(rng.choice(sel, size, replace=False))
        pts[j, : len(sel)], nrm[j, : len(sel)], msk[j, : len(sel)] = points[sel], normals[sel], True
    return Segments(points=jnp.asarray(pts), normals=jnp.asarray(nrm), mask=jnp.asarray(msk),
                    labels=jnp.asarray(labels, jnp.int32))
