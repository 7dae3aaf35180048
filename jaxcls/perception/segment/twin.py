"""The scale path's twin of the reference segmentation: the same algorithm in JAX with static shapes,
jittable and vmappable over episodes."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls.perception.foreground import check_cloud_shape, compact, foreground_mask
from jaxcls.perception.segment.common import (
    _PAIR_SHIFTS,
    Segments,
    _absorb_more,
    _absorb_step,
    _basin_centres,
    _cell_of,
    _count_rule,
    _estimated,
    _grid_size,
    _merge_more,
    _merge_step,
    _Merging,
    _order_segments,
    _pointer_jumps,
    _too_small,
    _vote_directions,
    _vote_radii,
    pack_segments,
)
from jaxcls.perception.segment.grid import (
    _NEIGHBOURS,
    _blur,
    _distance_transform,
    _fill_holes,
    _morph,
    _nearest_seed,
    _shifted,
)
from jaxcls.perception.settings import Spec


def _dense_points(x: jax.Array, valid: jax.Array, spec: Spec) -> jax.Array:
    """[P] bool: DBSCAN's noise removal on a grid of eps/2 cells. A point is core when the 3x3x3 cells around
    its own (a block 1.5 eps wide, close to DBSCAN's eps ball) hold >= ``dbscan_min_samples`` valid points;
    it is kept when one of those cells holds a core point (DBSCAN's core and border points). Only the
    points' neighbourhoods are read (27 gathers each), never the whole grid."""
    cell = 0.5 * spec.segmentation.dbscan_eps
    G = int(np.ceil(spec.roi_size / cell)) + 2  # one empty cell of margin on each side
    origin = jnp.asarray(spec.roi_center, x.dtype) - 0.5 * spec.roi_size - cell
    ijk = jnp.clip(jnp.floor((x - origin) / cell).astype(jnp.int32), 1, G - 2)
    flat = (ijk[:, 0] * G + ijk[:, 1]) * G + ijk[:, 2]
    offsets = jnp.asarray([(i * G + j) * G + k for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])

    def neighbourhood_sum(grid):
        # One neighbour cell at a time: [P] gathered live, not [P, 27].
        total, _ = jax.lax.scan(lambda acc, o: (acc + grid[flat + o].astype(jnp.int32), None),
                                jnp.zeros(flat.shape, jnp.int32), offsets)
        return total

    slot = jnp.where(valid, flat, G**3)  # out of bounds: dropped
    counts = jnp.zeros(G**3, jnp.int16).at[slot].add(1, mode="drop")  # valid points a cell
    core = valid & (neighbourhood_sum(counts) >= spec.segmentation.dbscan_min_samples)
    # The core points a cell, from the same buffer (updated in place: no second grid to zero): each valid
    # point takes back its 1 and adds 1 if it is core (core points are valid).
    counts = counts.at[slot].add(core.astype(jnp.int16) - 1, mode="drop")
    return valid & (neighbourhood_sum(counts) > 0)


def _footprint_field(x: jax.Array, normals: jax.Array, kept: jax.Array, spec: Spec
                     ) -> tuple[jax.Array, jax.Array]:
    """``footprint_field_reference`` in JAX: (occupancy [G, G] bool, field [G, G] f32)."""
    G = _grid_size(spec)
    ij = _cell_of(x, spec, xp=jnp)
    raw = jnp.zeros(G * G, bool).at[jnp.where(kept, ij[:, 0] * G + ij[:, 1], G * G)].set(True, mode="drop")
    raw = raw.reshape(G, G)
    occ = raw
    for _ in range(spec.segmentation.closing_steps):
        occ = _morph(occ, True)
    for _ in range(spec.segmentation.closing_steps):
        occ = _morph(occ, False)
    occ = _fill_holes(occ | raw, spec.segmentation.max_cc_iters)
    u, weight = _vote_directions(normals, spec, xp=jnp)
    weight = jnp.where(kept, weight, 0.0)

    def vote(votes: jax.Array, radius: jax.Array) -> tuple[jax.Array, None]:
        # One radius at a time: [M] votes live, not [M, R]. Points that do not vote (tops, noise, padding) are
        # sent out of bounds and dropped, rather than adding 0 to one cell: on a GPU those additions all
        # contend for that cell.
        tij = _cell_of(x + jnp.pad(radius * u, ((0, 0), (0, 1))), spec, xp=jnp)
        target = jnp.where(weight > 0, tij[:, 0] * G + tij[:, 1], G * G)
        return votes.at[target].add(weight, mode="drop"), None

    votes, _ = jax.lax.scan(vote, jnp.zeros(G * G, x.dtype), jnp.asarray(_vote_radii(spec), x.dtype))
    votes = votes.reshape(G, G)
    votes = _blur(votes * occ, spec.segmentation.vote_sigma)
    votes = votes / jnp.maximum(votes.max(), 1e-12)
    return occ, _distance_transform(occ) * jnp.maximum(votes, 0.0) ** spec.segmentation.vote_exponent


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
    for _ in range(_pointer_jumps(G)):
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


def _heightmap(x: jax.Array, kept: jax.Array, spec: Spec) -> jax.Array:
    """``_heightmap_np`` in JAX: [G, G] f32 the highest z (m) of the kept points in each cell, -inf where none."""
    G = _grid_size(spec)
    ij = _cell_of(x, spec, xp=jnp)
    target = jnp.where(kept, ij[:, 0] * G + ij[:, 1], G * G)  # dropped points out of bounds
    return jnp.full(G * G, -jnp.inf, x.dtype).at[target].max(x[:, 2], mode="drop").reshape(G, G)


def _flush_inputs(basin: jax.Array, height: jax.Array, K: int, tolerance: float
                  ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``_flush_inputs_np`` in JAX: ([K] f32 top, [K, K] i32 across, [K, K] i32 smooth)."""
    flat = basin.reshape(-1)
    # Cells of no basin out of bounds, dropped (never a sink slot: on a GPU its updates would serialise).
    top = jnp.full(K, -jnp.inf, height.dtype).at[jnp.where(flat >= 0, flat, K)].max(height.reshape(-1), mode="drop")
    across = jnp.zeros(K * K, jnp.int32)
    smooth = jnp.zeros(K * K, jnp.int32)
    for di, dj in _PAIR_SHIFTS:
        lb, hb = _shifted(basin, di, dj, -1), _shifted(height, di, dj, -jnp.inf)
        sel = ((basin >= 0) & (lb >= 0) & (basin != lb) & jnp.isfinite(height) & jnp.isfinite(hb)).reshape(-1)
        close = sel & (jnp.abs(height - hb) < tolerance).reshape(-1)
        a, b = flat, lb.reshape(-1)
        for pair in (a * K + b, b * K + a):
            across = across.at[jnp.where(sel, pair, K * K)].add(1, mode="drop")
            smooth = smooth.at[jnp.where(close, pair, K * K)].add(1, mode="drop")
    return top, across.reshape(K, K), smooth.reshape(K, K)


class _Lloyd(NamedTuple):
    """K-means' loop state: label [M] i32, centres [K, D], changed [] bool (a label moved), rounds [] i32."""

    label: jax.Array
    centres: jax.Array
    changed: jax.Array
    rounds: jax.Array


class _Split(NamedTuple):
    """The splitting loop's state: part [P] i32 each point's part, rounds [] i32."""

    part: jax.Array
    rounds: jax.Array


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

    def body(state: _Lloyd) -> _Lloyd:
        c = update(state.label, state.centres)
        new = assign(c)
        return _Lloyd(new, c, jnp.any((new != state.label) & (weight > 0)), state.rounds + 1)

    start = _Lloyd(assign(init), init, jnp.array(True), jnp.int32(0))
    end = jax.lax.while_loop(lambda s: s.changed & (s.rounds < iters), body, start)
    return end.label, end.centres


_SPLIT_SAMPLE = 4096  # points a 2-means split fits its centres on


def _split_until_n(part: jax.Array, y: jax.Array, kept: jax.Array, spec: Spec) -> jax.Array:
    """Split the part with the largest sum of squares by 2-means along its main axis until there are N."""
    N = spec.num_segments
    ys = y * jnp.asarray([1.0, 1.0, spec.segmentation.kmeans_z_weight], y.dtype)
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
        sub, sub_mask = compact(ys, sel, _SPLIT_SAMPLE)
        _, c = _kmeans(sub, sub_mask.astype(y.dtype), jnp.stack([centre - step, centre + step]),
                       spec.segmentation.kmeans_iters)
        half = jnp.sum((ys - c[1]) ** 2, axis=1) < jnp.sum((ys - c[0]) ** 2, axis=1)
        return jnp.where((count[g] >= 2) & sel & half, n, part)

    def needed(state: _Split) -> jax.Array:  # a while loop, not a cond: under vmap it stops when no episode needs it
        return (jnp.max(jnp.where(kept, state.part, -1)) + 1 < N) & (state.rounds < N - 1)

    def split(state: _Split) -> _Split:
        return _Split(body(state.rounds, state.part), state.rounds + 1)

    return jax.lax.while_loop(needed, split, _Split(part, jnp.int32(0))).part


def cluster_jax(spec: Spec, x: jax.Array, normals: jax.Array, valid: jax.Array) -> jax.Array:
    """[P] i32 partition of the valid points ``x: [P, 3]`` (unit ``normals``) into N segments (N known) or 0
    to N (N estimated: ``shapes.num_objects``), -1 = invalid, noise or a dropped fragment: the JAX twin of
    ``cluster_reference``."""
    N, K = spec.num_segments, spec.segmentation.max_basins
    kept = _dense_points(x, valid, spec)
    occ, field = _footprint_field(x, normals, kept, spec)
    basin, peak, exists = _basins(field, occ, K)
    centre, size = _basin_centres(basin, K, xp=jnp)

    estimated, rule = _estimated(spec), _count_rule(spec)
    state = _Merging(exists, _saddles(basin, field, K), centre, size, jnp.arange(K))
    if rule is not None:
        flush = _flush_inputs(basin, _heightmap(x, kept, spec), K, rule.flush_height)
        state = state._replace(**dict(zip(("top", "across", "smooth"), flush, strict=True)))
    state = jax.lax.while_loop(lambda s: _merge_more(jnp, s, peak, N, rule),
                               lambda s: _merge_step(jnp, s, peak, rule), state)
    if rule is not None and rule.absorb_cells > 0:
        state = jax.lax.while_loop(lambda s: _absorb_more(jnp, s, peak, rule),
                                   lambda s: _absorb_step(jnp, s, peak, rule), state)
    ij = _cell_of(x, spec, xp=jnp)
    group = state.group[jnp.maximum(basin[ij[:, 0], ij[:, 1]], 0)]
    kept = kept & ~_too_small(state, spec, xp=jnp)[group]
    # Which groups keep a point: a one-hot reduction, not a scatter onto K slots (P updates contending for
    # K addresses serialise on a GPU: 2.6 ms a call at 512 episodes, BENCHMARKS.md).
    present = jnp.any(kept[:, None] & (group[:, None] == jnp.arange(K)), axis=0)
    part = (jnp.cumsum(present) - 1)[group].astype(jnp.int32)
    if not estimated:
        part = _split_until_n(part, x, kept, spec)
    enough = jnp.sum(kept) >= (1 if estimated else N)
    return jnp.where(kept & enough, part, -1).astype(jnp.int32)


@jax.jit
def segment_jax(spec: Spec, points: jax.Array, normals: jax.Array, mask: jax.Array) -> Segments:
    """Scale-path segmentation, the twin of ``segment``: jittable, vmappable over episodes.

    points, normals: [P, 3] (m, unit); mask: [P] bool. Same contract as ``segment`` (N known: N segments;
    N estimated: the count's segments, then empty slots); the partition and the count agree with it
    (adjusted Rand index, tested on rendered scenes).
    """
    check_cloud_shape(points, mask, "segment_jax", normals)
    points = jnp.asarray(points, jnp.float32)
    fg = foreground_mask(spec, points, mask)
    x = jnp.where(fg[:, None], points, 0.0)
    normals = jnp.where(fg[:, None], jnp.nan_to_num(jnp.asarray(normals, jnp.float32)), 0.0)
    labels = _order_segments(cluster_jax(spec, x, normals, fg), x, spec.num_segments)
    return pack_segments(x, normals, labels, spec.num_segments, spec.points_per_segment)
