"""The reference path: scikit-learn DBSCAN and K-means, SciPy grid labelling, on the host (one episode)."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls.perception.foreground import check_cloud_shape, foreground_mask
from jaxcls.perception.segment.common import (
    _PAIR_SHIFTS,
    Segments,
    _absorb_more,
    _absorb_step,
    _basin_centres,
    _cell_of,
    _count_rule,
    _estimated,
    _gaussian_kernel,
    _grid_size,
    _merge_more,
    _merge_step,
    _Merging,
    _order_segments,
    _pointer_jumps,
    _too_small,
    _vote_targets,
    pack_segments,
)
from jaxcls.perception.settings import Spec


def _morph_np(m: np.ndarray, op) -> np.ndarray:
    """3x3 square erosion (op = np.minimum) or dilation (np.maximum) of ``m: [G, G]`` bool, outside = False."""
    G = m.shape[0]
    p = np.pad(m, 1)
    out = p[1:-1, 1:-1].copy()
    for di in (0, 1, 2):
        for dj in (0, 1, 2):
            out = op(out, p[di:di + G, dj:dj + G])
    return out


def footprint_field_reference(spec: Spec, y: np.ndarray, normals: np.ndarray
                              ) -> tuple[np.ndarray, np.ndarray]:
    """(occupancy [G, G] bool, field [G, G] f64) of points ``y: [M, 3]`` with unit ``normals: [M, 3]``.

    Occupancy: the points' cells, closed by ``closing_steps`` 3x3 steps, holes filled. Field: distance to
    empty space (cells) times the normalised, blurred centre votes to the power ``vote_exponent``.
    """
    from scipy import ndimage

    G = _grid_size(spec)
    ij = _cell_of(y, spec)
    raw = np.zeros((G, G), bool)
    raw[ij[:, 0], ij[:, 1]] = True
    occ = raw
    for _ in range(spec.segmentation.closing_steps):
        occ = _morph_np(occ, np.maximum)
    for _ in range(spec.segmentation.closing_steps):
        occ = _morph_np(occ, np.minimum)
    occ = ndimage.binary_fill_holes(occ | raw)
    distance = ndimage.distance_transform_edt(occ)
    targets, weight = _vote_targets(y, normals, spec)
    tij = _cell_of(targets.reshape(-1, 3), spec)
    votes = np.zeros((G, G))
    np.add.at(votes, (tij[:, 0], tij[:, 1]), np.repeat(weight, spec.segmentation.vote_radii))
    kernel = _gaussian_kernel(spec.segmentation.vote_sigma)
    votes = ndimage.convolve1d(ndimage.convolve1d(votes * occ, kernel, axis=0, mode="reflect"), kernel, axis=1,
                               mode="reflect")
    votes = votes / max(votes.max(), 1e-12)
    return occ, distance * np.maximum(votes, 0.0) ** spec.segmentation.vote_exponent


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
    for _ in range(_pointer_jumps(G)):
        up = up[up]
    root = np.where(occ.ravel(), up, -1)
    peaks, basin = np.unique(root[root >= 0], return_inverse=True)
    out = np.full(G * G, -1)
    out[root >= 0] = basin
    return out.reshape(G, G), field.ravel()[peaks]


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


def _heightmap_np(spec: Spec, y: np.ndarray) -> np.ndarray:
    """[G, G] f64 the highest z (m) of the points ``y: [M, 3]`` in each footprint cell, -inf where none."""
    G = _grid_size(spec)
    ij = _cell_of(y, spec)
    height = np.full((G, G), -np.inf)
    np.maximum.at(height, (ij[:, 0], ij[:, 1]), y[:, 2])
    return height


def _flush_inputs_np(basin: np.ndarray, height: np.ndarray, K: int, tolerance: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the flush rule reads (``_Merging``'s ``top``, ``across``, ``smooth``) of the basins ``basin: [G, G]``
    (-1 = none) over the heightmap ``height: [G, G]`` (``_heightmap_np``): ([K] each basin's highest z, m, -inf
    without points; [K, K] i64 adjacent cell pairs of two basins both holding points; [K, K] i64 those whose
    heights differ by less than ``tolerance`` m)."""
    G = basin.shape[0]
    top = np.full(K, -np.inf)
    cells = basin >= 0
    np.maximum.at(top, basin[cells], height[cells])
    across, smooth = np.zeros((K, K), np.int64), np.zeros((K, K), np.int64)
    bp, hp = np.pad(basin, 1, constant_values=-1), np.pad(height, 1, constant_values=-np.inf)
    for di, dj in _PAIR_SHIFTS:
        lb, hb = bp[1 + di:1 + di + G, 1 + dj:1 + dj + G], hp[1 + di:1 + di + G, 1 + dj:1 + dj + G]
        sel = (basin >= 0) & (lb >= 0) & (basin != lb) & np.isfinite(height) & np.isfinite(hb)
        a, b = basin[sel], lb[sel]
        close = np.abs(height[sel] - hb[sel]) < tolerance
        for m, w in ((across, np.ones(len(a), np.int64)), (smooth, close.astype(np.int64))):
            np.add.at(m, (a, b), w)
            np.add.at(m, (b, a), w)
    return top, across, smooth


def _principal_split(x: np.ndarray) -> np.ndarray:
    """[2, 3] initial centres for splitting ``x: [M, 3]``: its mean -/+ one std along its main axis."""
    centre = x.mean(0)
    w, v = np.linalg.eigh(np.cov((x - centre).T, bias=True))
    step = np.sqrt(max(w[-1], 0.0)) * v[:, -1]
    return np.stack([centre - step, centre + step])


class _ReferenceParts(NamedTuple):
    """The reference path's footprint watershed after the persistence merge, before fragments are dropped or
    parts split (``cluster_reference`` reads it; ``experiments.counting.explain_segments`` too).

    good: [M] bool the points DBSCAN keeps; occ: [G, G] bool footprint; field: [G, G] f64 the watershed's
    field; basin: [G, G] i64 each cell's basin, -1 off; peak: [K] f64 each basin's peak height; merged: the
    ``_Merging`` state at the end (``group`` [K] the basin each joined, ``alive`` the surviving groups);
    group: [len(y)] i64 the group of each kept point (``y = x[good]``)."""

    good: np.ndarray
    occ: np.ndarray
    field: np.ndarray
    basin: np.ndarray
    peak: np.ndarray
    merged: _Merging
    group: np.ndarray


def _watershed_reference(spec: Spec, x: np.ndarray, normals: np.ndarray) -> _ReferenceParts | None:
    """DBSCAN's noise removal, the footprint field's watershed and the persistence merge (``_merge_step``,
    while ``_merge_more``; with the count estimated then ``_absorb_step`` while ``_absorb_more``) of foreground
    points ``x: [M, 3]`` m with unit ``normals: [M, 3]``; None when
    fewer than one point (N estimated) or N points (N known) remain."""
    from sklearn.cluster import DBSCAN

    N = spec.num_segments
    least = 1 if _estimated(spec) else N  # fewer points than this: no segment
    if len(x) < least:
        return None
    cfg = spec.segmentation
    good = DBSCAN(eps=cfg.dbscan_eps, min_samples=cfg.dbscan_min_samples).fit_predict(x) >= 0
    y = x[good]
    if len(y) < least:
        return None
    occ, field = footprint_field_reference(spec, y, normals[good])
    basin, peak = _basins_np(field, occ)
    K = len(peak)
    state = _Merging(np.ones(K, bool), _saddles_np(basin, field, K), *_basin_centres(basin, K), np.arange(K))
    rule = _count_rule(spec)
    if rule is not None:
        flush = _flush_inputs_np(basin, _heightmap_np(spec, y), K, rule.flush_height)
        state = state._replace(**dict(zip(("top", "across", "smooth"), flush, strict=True)))
    while _merge_more(np, state, peak, N, rule):
        state = _merge_step(np, state, peak, rule)
    while rule is not None and _absorb_more(np, state, peak, rule):
        state = _absorb_step(np, state, peak, rule)
    ij = _cell_of(y, spec)
    return _ReferenceParts(good, occ, field, basin, peak, state, state.group[basin[ij[:, 0], ij[:, 1]]])


def cluster_reference(spec: Spec, x: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """[M] i64 partition of foreground points ``x: [M, 3]`` (unit ``normals``) into segments, -1 = noise.

    DBSCAN drops noise; the footprint field's watershed basins are merged by persistence (``_merge_step``).
    N known (``shapes.num_objects``): merged down to N; while there are fewer than N parts, the one with the
    largest sum of squares is split by 2-means. N estimated: merged while ``_merge_more`` says so (a
    relative persistence below ``merge_persistence``, or more parts than the ``num_segments`` slots), parts under
    ``absorb_area`` joined to a larger touching part (``_absorb_costs``), parts with a footprint under
    ``min_object_area`` left dropped (-1), never split: 0 to ``num_segments`` parts.
    """
    from sklearn.cluster import KMeans

    N = spec.num_segments
    estimated = _estimated(spec)
    labels = np.full(len(x), -1, np.int64)
    parts = _watershed_reference(spec, x, normals)
    if parts is None:
        return labels
    cfg = spec.segmentation
    good, group = parts.good, parts.group
    y = x[good]
    keep = ~_too_small(parts.merged, spec)[group]
    part = np.full(len(y), -1, np.int64)
    if keep.any():
        part[keep] = np.unique(group[keep], return_inverse=True)[1]
    ys = y * np.array([1.0, 1.0, cfg.kmeans_z_weight])
    while not estimated and part.max() + 1 < N:
        sse = [((ys[part == j] - ys[part == j].mean(0)) ** 2).sum() for j in range(part.max() + 1)]
        sel = np.flatnonzero(part == int(np.argmax(sse)))
        if len(sel) < 2:
            break
        km = KMeans(n_clusters=2, init=_principal_split(ys[sel]), n_init=1, max_iter=cfg.kmeans_iters, tol=0.0)
        part[sel[km.fit(ys[sel]).labels_ == 1]] = part.max() + 1
    labels[good] = part
    return labels


def _labels_host(spec: Spec, points: np.ndarray, normals: np.ndarray, fg: np.ndarray) -> np.ndarray:
    """[P] i32 ``cluster_reference``'s labels of the foreground points ``fg`` [P] (-1 elsewhere)."""
    labels = np.full(len(points), -1, np.int32)
    labels[fg] = cluster_reference(spec, np.asarray(points, np.float64)[fg], np.asarray(normals, np.float64)[fg])
    return labels


def segment(spec: Spec, points: np.ndarray | jax.Array, normals: np.ndarray | jax.Array,
            mask: np.ndarray | jax.Array) -> Segments:
    """Reference segmentation (scikit-learn on the host) of a padded cloud into N = ``num_segments`` segment
    slots: exactly N with ``shapes.num_objects = known``; with ``estimated``, one a counted object, the slots
    beyond the count empty.

    points, normals: [P, 3] (m, unit); mask: [P] bool. Foreground is ``foreground_mask``; segments are
    ordered by centroid x then y, empty slots last, and packed by ``pack_segments``. N known and fewer
    foreground points than N, or none: all masks empty, labels -1. The clustering runs on the host through
    ``jax.pure_callback``, so this traces into a jitted move like the JAX twin (vmapped: one episode after
    another).
    """
    check_cloud_shape(points, mask, "segment", normals)
    points = jnp.asarray(points, jnp.float32)
    fg = foreground_mask(spec, points, mask)
    points = jnp.where(fg[:, None], points, 0.0)
    normals = jnp.where(fg[:, None], jnp.nan_to_num(jnp.asarray(normals, jnp.float32)), 0.0)
    host = functools.partial(_labels_host, spec.replace(classifier=None))
    labels = jax.pure_callback(host, jax.ShapeDtypeStruct(fg.shape, jnp.int32), points, normals, fg,
                               vmap_method="sequential")
    labels = _order_segments(labels, points, spec.num_segments)
    return pack_segments(points, normals, labels, spec.num_segments, spec.points_per_segment)
