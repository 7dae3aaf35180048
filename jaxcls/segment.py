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
    stride = jnp.maximum(count.astype(jnp.float32) / size, 1.0)[jnp.clip(labels, 0, n - 1)]
    slot = jnp.floor(rank.astype(jnp.float32) / stride).astype(jnp.int32)
    keep = (labels >= 0) & (rank == jnp.ceil(slot.astype(jnp.float32) * stride).astype(jnp.int32)) & (slot < size)
    row, col = jnp.where(keep, labels, n), jnp.where(keep, slot, 0)
    pts = jnp.zeros((n + 1, size, 3), jnp.float32).at[row, col].set(jnp.asarray(points, jnp.float32))[:n]
    nrm = jnp.zeros((n + 1, size, 3), jnp.float32).at[row, col].set(jnp.asarray(normals, jnp.float32))[:n]
    msk = jnp.zeros((n + 1, size), bool).at[row, col].set(keep)[:n]
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
    labels[fg] = cluster_reference(points[fg].astype(np.float64), config)
    labels = _order_segments(labels, points, config.num_segments)
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
        grid = jnp.zeros(G**3, jnp.int16).at[flat].add(flags.astype(jnp.int16))
        return jnp.sum(grid[around], axis=1, dtype=jnp.int32)

    core = valid & (neighbourhood_sum(valid) >= config.dbscan_min_samples)
    return valid & (neighbourhood_sum(core) > 0)


def _shifted(a: jax.Array, di: int, dj: int, fill) -> jax.Array:
    """``a: [G, G, ...]`` moved so that out[i, j] = a[i + di, j + dj], ``fill`` outside."""
    G, k = a.shape[0], max(abs(di), abs(dj), 1)
    p = jnp.pad(a, [(k, k), (k, k)] + [(0, 0)] * (a.ndim - 2), constant_values=fill)
    return p[k + di:k + di + G, k + dj:k + dj + G]


_NEIGHBOURS = [(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)]


def _morph(m: jax.Array, dilate: bool) -> jax.Array:
    """3x3 square dilation or erosion of ``m: [G, G]`` bool, outside = False (as ``_morph_np``)."""
    out = m
    for di, dj in _NEIGHBOURS:
        out = (out | _shifted(m, di, dj, False)) if dilate else (out & _shifted(m, di, dj, False))
    return out


def _components(occ: jax.Array, max_iters: int) -> jax.Array:
    """[G, G] i32 8-connected component of each occupied cell, named by its largest flat cell index; -1 off.

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
        for di, dj in _NEIGHBOURS:
            nb = jnp.maximum(nb, _shifted(rep, di, dj, -1))
        target = jnp.where(occ_flat, rep.reshape(-1), G * G)
        new = jnp.concatenate([parent, jnp.zeros(1, jnp.int32)]).at[target].max(nb.reshape(-1))[:-1]
        for _ in range(4):
            new = new[new]
        return new, jnp.any(new != parent), i + 1

    parent, _, _ = jax.lax.while_loop(lambda s: s[1] & (s[2] < max_iters), step, (parent, jnp.array(True), 0))
    return jnp.where(occ, parent.reshape(G, G), -1)


def _footprint_cores(occ: jax.Array, config: SegmentConfig) -> jax.Array:
    """[G, G] i32 core index per cell (-1 = none) of a footprint occupancy, as ``footprint_cores_reference``."""
    G, N = occ.shape[0], config.num_segments
    for _ in range(config.closing_steps):
        occ = _morph(occ, True)
    for _ in range(config.closing_steps):
        occ = _morph(occ, False)

    def components(occ):
        labels = _components(occ, config.max_cc_iters).reshape(-1)
        sizes = jnp.zeros(G * G, jnp.int32).at[jnp.maximum(labels, 0)].add(labels >= 0)
        return labels, sizes, jnp.minimum(jnp.sum(sizes >= config.min_core_cells), N)

    def erode(state):  # the next erosion; kept when it has more cores (so the first with the most wins)
        occ, level, best = state
        occ = _morph(occ, False)
        new = components(occ)
        best = jax.tree.map(lambda a, b: jnp.where(new[2] > best[2], a, b), new, best)
        return occ, level + 1, best

    _, _, (flat, sizes, _) = jax.lax.while_loop(lambda s: (s[2][2] < N) & (s[1] < config.max_erosion), erode,
                                                (occ, 0, components(occ)))
    # Order cores by size, ties by raster order of their first cell (scipy's label order).
    first = jnp.full(G * G, G * G, jnp.int32).at[jnp.maximum(flat, 0)].min(
        jnp.where(flat >= 0, jnp.arange(G * G, dtype=jnp.int32), G * G))
    is_core = sizes >= config.min_core_cells
    order = jnp.lexsort((first, -sizes, ~is_core))[: config.max_cores]
    rank = jnp.full(G * G, -1, jnp.int32).at[order].set(jnp.where(is_core[order], jnp.arange(len(order)), -1))
    return jnp.where(flat >= 0, rank[jnp.maximum(flat, 0)], -1).reshape(G, G)


def _nearest_core(cores: jax.Array) -> jax.Array:
    """[G, G] i32 index of the nearest core cell's core (Euclidean, in cells) of every cell; -1 when none.

    Jump flooding: every cell keeps the nearest of the seeds its 8 neighbours at distance k hold, for
    k = G/2, ..., 2, 1, 1 (the last pass repairs the rare misses of the halving passes).
    """
    G = cores.shape[0]
    ii, jj = jnp.meshgrid(jnp.arange(G), jnp.arange(G), indexing="ij")
    seed = jnp.where(cores >= 0, ii * G + jj, -1)

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
    return jnp.where(seed >= 0, cores.reshape(-1)[jnp.maximum(seed, 0)], -1)


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

    def maybe(i, part):
        n = jnp.max(jnp.where(kept, part, -1)) + 1
        return jax.lax.cond(n < N, lambda p: body(i, p), lambda p: p, part)

    return jax.lax.fori_loop(0, N - 1, maybe, part)


def cluster_jax(x: jax.Array, valid: jax.Array, config: SegmentConfig) -> jax.Array:
    """[P] i32 partition of the valid points ``x: [P, 3]`` into N segments (-1 = invalid or noise).

    The JAX twin of ``cluster_reference``: grid noise removal, footprint cores by erosion and label
    propagation, weighted K-means on core centres, nearest-core assignment, 2-means splits.
    """
    N, G = config.num_segments, _grid_size(config)
    kept = _dense_points(x, valid, config)
    ij = _cell_of(x, config, xp=jnp)
    cell = ij[:, 0] * G + ij[:, 1]
    occ = jnp.zeros(G * G, bool).at[cell].max(kept).reshape(G, G)
    cores = _footprint_cores(occ, config)
    C = config.max_cores
    flat = cores.reshape(-1)
    centres_xy = jnp.asarray(_cell_centres(config).reshape(-1, 2), x.dtype)
    onehot = jax.nn.one_hot(flat, C, dtype=x.dtype)  # -1 gives a zero row
    sizes = onehot.sum(0)
    core_xy = (onehot.T @ centres_xy) / jnp.maximum(sizes, 1)[:, None]
    n_cores = jnp.sum(sizes > 0)
    km, _ = _kmeans(core_xy, sizes, core_xy[:N], config.kmeans_iters)
    group = jnp.where(n_cores > N, km, jnp.arange(C))  # the paper's K-means on cluster centres
    nearest = _nearest_core(cores).reshape(-1)
    part = jnp.where(nearest[cell] >= 0, group[jnp.maximum(nearest[cell], 0)], 0)
    present = jnp.zeros(C, bool).at[part].max(kept)
    part = (jnp.cumsum(present) - 1)[part].astype(jnp.int32)
    part = _split_until_n(part, x, kept, config)
    enough = jnp.sum(kept) >= N
    return jnp.where(kept & enough, part, -1).astype(jnp.int32)


def _order_segments_jax(labels: jax.Array, x: jax.Array, n: int) -> jax.Array:
    """``_order_segments`` in JAX: segments by centroid x then y, empty ones last."""
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
    labels = _order_segments_jax(cluster_jax(x, fg, config), x, config.num_segments)
    return pack_segments(x, normals, labels, config.num_segments, config.points_per_segment)
