"""What both segmentation paths share: the footprint grid, centre votes, the persistence merge step,
segment ordering and packing (``xp`` = numpy or jax.numpy where a function serves both)."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxcls.perception.foreground import strided_slots
from jaxcls.perception.settings import ObjectCount, Spec


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


def _grid_size(spec: Spec) -> int:
    return int(np.ceil(spec.roi_size / spec.segmentation.footprint_cell))


def _cell_of(x: np.ndarray | jax.Array, spec: Spec, xp=np) -> np.ndarray | jax.Array:
    """[M, 2] i32 footprint cell (i along x, j along y) of world points ``x: [M, 3]``, clipped to the grid."""
    origin = xp.asarray(spec.roi_center[:2], x.dtype) - 0.5 * spec.roi_size
    ij = xp.floor((x[:, :2] - origin) / spec.segmentation.footprint_cell).astype(xp.int32)
    return xp.clip(ij, 0, _grid_size(spec) - 1)


def _gaussian_kernel(sigma: float) -> np.ndarray:
    """SciPy's ``gaussian_filter`` kernel (truncated at 4 sigma)."""
    radius = int(4.0 * sigma + 0.5)
    k = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    return k / k.sum()


def _vote_radii(spec: Spec) -> np.ndarray:
    """[R] the radii (m) at which side-wall points vote for their object's axis."""
    cfg = spec.segmentation
    return np.linspace(cfg.footprint_cell, cfg.vote_max_radius, cfg.vote_radii)


def _vote_directions(normals: np.ndarray | jax.Array, spec: Spec, xp=np):
    """([M, 2] unit xy directions -n_xy along which points vote, [M] weights |n_xy|, 0 = no vote)."""
    nxy = normals[:, :2]
    h = xp.sqrt(xp.sum(nxy**2, axis=1))
    weight = xp.where(h > spec.segmentation.vote_min_horizontal, h, 0.0)
    return -nxy / xp.maximum(h, 1e-12)[:, None], weight


def _vote_targets(x: np.ndarray | jax.Array, normals: np.ndarray | jax.Array, spec: Spec, xp=np):
    """Where side-wall points vote for their object's axis: ([M, R, 3] points, [M] weights |n_xy|, 0 = no vote)."""
    u, weight = _vote_directions(normals, spec, xp)
    radii = xp.asarray(_vote_radii(spec), x.dtype)
    xy = x[:, None, :2] + radii[None, :, None] * u[:, None, :]
    return xp.concatenate([xy, xp.zeros_like(xy[..., :1])], axis=-1), weight


def _pointer_jumps(G: int) -> int:
    """Pointer-jumping rounds after which every steepest-ascent chain of a [G, G] grid reaches its peak
    (a chain visits each cell at most once: 2^rounds >= G^2; 14 for the default 120^2 grid)."""
    return max(1, int(np.ceil(np.log2(G * G))))


_PAIR_SHIFTS = ((0, 1), (1, 0), (1, 1), (1, -1))  # each 8-neighbour pair once


class _Merging(NamedTuple):
    """The persistence merge's state over K basins: alive [K] bool; saddle [K, K] the highest saddle between
    two basins (-inf: none); centre [K, 2] cells; size [K] cells; group [K] the basin each one has joined.

    With the count estimated (``_count_rule`` not None), what the flush rule reads, else None: top [K] the
    highest point of each basin above the table, m (-inf: no point); across [K, K] i32 adjacent cell pairs of
    two basins that both hold points; smooth [K, K] i32 those of them whose highest points differ by less than
    ``flush_height``."""

    alive: np.ndarray | jax.Array
    saddle: np.ndarray | jax.Array
    centre: np.ndarray | jax.Array
    size: np.ndarray | jax.Array
    group: np.ndarray | jax.Array
    top: np.ndarray | jax.Array | None = None
    across: np.ndarray | jax.Array | None = None
    smooth: np.ndarray | jax.Array | None = None


class _CountRule(NamedTuple):
    """The merge rule with the count estimated (``segmentation``'s settings; ``_count_rule``): two touching
    basins merge while the lower one's relative persistence is below ``persistence``, or below
    ``flush_persistence`` where they are flush: their highest points within ``flush_height`` m of each other
    and at least half of the cell pairs across their boundary within ``flush_height`` too (one surface, not
    two objects side by side). After that merge (``_absorb_costs``): a part of fewer than ``absorb_cells`` cells
    that touches a larger live part of at least ``object_cells`` (``min_object_area``) joins it, whatever its
    persistence (``absorb_cells`` 0: never)."""

    persistence: float
    flush_persistence: float
    flush_height: float
    absorb_cells: float = 0.0
    object_cells: float = 0.0


def _count_rule(spec: Spec) -> _CountRule | None:
    """The estimated count's merge rule (``_CountRule``), None with N known."""
    if not _estimated(spec):
        return None
    cfg = spec.segmentation
    cell = cfg.footprint_cell ** 2
    return _CountRule(cfg.merge_persistence, cfg.flush_persistence, cfg.flush_height, cfg.absorb_area / cell,
                      cfg.min_object_area / cell)


def _merge_costs(xp, state: _Merging, peak, rule: _CountRule | None = None):
    """What merging each basin would cost: ([K] cost, inf for a basin that cannot merge; [K] i32 the basin it
    would join).

    A live basin joins the higher live basin it shares the highest saddle with. A basin with no saddle to a
    higher one (a separate DBSCAN cluster) is separated from it by empty space, where the field is 0: its
    saddle is 0 and it joins the nearest higher basin (the paper's merge of cluster centres). ``rule`` None (a
    known N): the cost is the persistence peak - saddle (field units), so that fragments go early and separate
    objects last. With the count estimated (``rule``): (peak - saddle) / peak, in [0, 1], comparable across
    object sizes, scaled by ``persistence / flush_persistence`` where the two basins are flush (``_CountRule``),
    so that a cost below ``persistence`` is the rule's merge; a basin apart on the table costs 1 + peak / the
    highest live peak, above every touching merge, smallest first.
    """
    alive, saddle, centre = state.alive, state.saddle, state.centre
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
    if rule is not None:
        scale = xp.maximum(peak, 1e-12)
        highest = xp.maximum(xp.max(xp.where(alive, peak, 0.0)), 1e-12)
        relative = (peak - xp.where(linked, top, 0.0)) / scale
        relative = relative * xp.where(_flush(xp, state, up, rule), rule.persistence / rule.flush_persistence, 1.0)
        cost = xp.where(linked, relative, 1.0 + peak / highest)
    else:
        cost = xp.where(linked, peak - top, peak)  # no saddle: the empty space between, where the field is 0
    cost = xp.where(alive & xp.any(higher, axis=1), cost, xp.inf)
    return cost, xp.where(linked, up, near)


def _flush(xp, state: _Merging, up, rule: _CountRule):
    """[K] bool: each basin flush with basin ``up`` [K] (``_CountRule``): highest points within
    ``flush_height`` and at least half of the cell pairs across their boundary too (none across: not flush)."""
    rows = xp.arange(up.shape[0])
    across, smooth = state.across[rows, up], state.smooth[rows, up]
    top = xp.maximum(state.top, -1e9)  # a basin without points (-inf) has none across either
    same_top = xp.abs(top - top[up]) < rule.flush_height
    return same_top & (across > 0) & (2 * smooth >= across)


def _merge_more(xp, state: _Merging, peak, slots: int, rule: _CountRule | None):
    """[] bool whether the persistence merge goes on: while more than ``slots`` basins live, and, with the count
    estimated (``rule`` not None), while the cheapest merge's cost is below ``rule.persistence``. Shared by both
    paths."""
    more = xp.sum(state.alive) > slots
    if rule is None:
        return more
    cost, _ = _merge_costs(xp, state, peak, rule)
    return more | (xp.min(cost) < rule.persistence)


def _merge_step(xp, state: _Merging, peak, rule: _CountRule | None = None) -> _Merging:
    """One persistence merge: the live basin with the lowest cost (``_merge_costs``) joins its target basin;
    the target's saddles become the higher of the two rows, its centre the size-weighted mean (with the count
    estimated: its top the higher, its boundary counts the sums). Shared by both paths (``xp`` = numpy or
    jax.numpy)."""
    cost, target = _merge_costs(xp, state, peak, rule)
    i = xp.argmin(cost)
    return _join(xp, state, i, target[i])


def _absorb_costs(xp, state: _Merging, peak, rule: _CountRule):
    """The absorbing step after the persistence merge (``_CountRule.absorb_cells``): ([K] cost, inf for a part
    that is not absorbed; [K] i32 the part it joins). A live part of fewer than ``absorb_cells`` cells (a jug's
    handle, a bowl's second wall) joins, of the live parts that touch it (share a saddle) and are larger than it
    and at least ``object_cells`` (parts that stand as objects), the one it shares the highest saddle with; its
    cost is its relative persistence to that part, (peak - saddle) / peak, lowest first. A part only grows when
    it absorbs, so no part reaches ``object_cells`` by absorbing: with ``absorb_cells <= object_cells`` the count
    is the persistence merge's, only fragments that would be dropped join their neighbour."""
    K = peak.shape[0]
    ar = xp.arange(K)
    size = state.size
    host = state.alive[None, :] & (ar[None, :] != ar[:, None]) & (size[None, :] > size[:, None]) & (
        size[None, :] >= rule.object_cells)
    touch = xp.where(host, state.saddle, -xp.inf)
    joins = xp.argmax(touch, axis=1)
    edge = xp.take_along_axis(touch, joins[:, None], axis=1)[:, 0]
    small = state.alive & (size < rule.absorb_cells) & (edge > -xp.inf)
    relative = (peak - xp.where(small, edge, 0.0)) / xp.maximum(peak, 1e-12)
    return xp.where(small, relative, xp.inf), joins


def _absorb_more(xp, state: _Merging, peak, rule: _CountRule):
    """[] bool whether a part is left to absorb (``_absorb_costs``; never with ``absorb_cells`` 0)."""
    if rule.absorb_cells <= 0:
        return xp.asarray(False)
    cost, _ = _absorb_costs(xp, state, peak, rule)
    return xp.min(cost) < xp.inf


def _absorb_step(xp, state: _Merging, peak, rule: _CountRule) -> _Merging:
    """One absorption (``_absorb_costs``): the part with the lowest cost joins its part (``_join``)."""
    cost, target = _absorb_costs(xp, state, peak, rule)
    i = xp.argmin(cost)
    return _join(xp, state, i, target[i])


def _join(xp, state: _Merging, i, t) -> _Merging:
    """Basin ``i`` joins basin ``t``: the target's saddles become the higher of the two rows, its centre the
    size-weighted mean (with the count estimated: its top the higher, its boundary counts the sums)."""
    ar = xp.arange(state.alive.shape[0])
    row = xp.maximum(state.saddle[t], state.saddle[i])
    row = xp.where(ar == t, -xp.inf, row)
    size, centre = state.size, state.centre
    joined = (centre[t] * size[t] + centre[i] * size[i]) / (size[t] + size[i])
    new = {"saddle": _set_cross(xp, state.saddle, t, row), "centre": _set_row(xp, centre, t, joined),
           "size": _set_row(xp, size, t, size[t] + size[i]), "alive": _set_row(xp, state.alive, i, False),
           "group": xp.where(state.group == i, t, state.group)}
    if state.top is not None:
        new["top"] = _set_row(xp, state.top, t, xp.maximum(state.top[t], state.top[i]))
        for name in ("across", "smooth"):
            m = getattr(state, name)
            new[name] = _set_cross(xp, m, t, xp.where(ar == t, 0, m[t] + m[i]))
    return state._replace(**new)


def _set_row(xp, a, i, value):
    """``a`` with ``a[i] = value`` (a copy with NumPy, ``.at`` with JAX)."""
    if xp is np:
        a = a.copy()
        a[i] = value
        return a
    return a.at[i].set(value)


def _set_cross(xp, m, i, row):
    """Symmetric ``m [K, K]`` with row and column ``i`` set to ``row [K]``."""
    if xp is np:
        m = m.copy()
        m[i], m[:, i] = row, row
        return m
    return m.at[i].set(row).at[:, i].set(row)


def _estimated(spec: Spec) -> bool:
    """Whether the number of objects is estimated (``shapes.num_objects``), not given as ``num_segments``."""
    return spec.config.shapes.num_objects is ObjectCount.estimated


def _too_small(state: _Merging, spec: Spec, xp=np):
    """[K] bool: with the count estimated, the live groups whose footprint (cells, closed and filled) covers
    less than ``min_object_area`` m^2: fragments, dropped (never with N known)."""
    if not _estimated(spec):
        return xp.zeros(state.alive.shape, bool)
    area = state.size * spec.segmentation.footprint_cell ** 2
    return state.alive & (area < spec.segmentation.min_object_area)


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


def _order_segments(labels: jax.Array, x: jax.Array, n: int) -> jax.Array:
    """Relabel segments by centroid x then y, empty ones last, so that the order is deterministic (both
    paths)."""
    onehot = jax.nn.one_hot(labels, n, dtype=x.dtype)
    count = onehot.sum(0)
    mean = (onehot.T @ x[:, :2]) / jnp.maximum(count, 1)[:, None]
    order = jnp.lexsort((mean[:, 1], mean[:, 0], count == 0))
    remap = jnp.zeros(n, jnp.int32).at[order].set(jnp.arange(n, dtype=jnp.int32))
    return jnp.where(labels >= 0, remap[jnp.maximum(labels, 0)], -1)


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
    slot, keep = strided_slots(rank, count[jnp.clip(labels, 0, n - 1)], size)
    keep &= labels >= 0
    row, col = jnp.where(keep, labels, n), jnp.where(keep, slot, 0)
    pts = jnp.zeros((n, size, 3), jnp.float32).at[row, col].set(jnp.asarray(points, jnp.float32), mode="drop")
    nrm = jnp.zeros((n, size, 3), jnp.float32).at[row, col].set(jnp.asarray(normals, jnp.float32), mode="drop")
    msk = jnp.zeros((n, size), bool).at[row, col].set(True, mode="drop")
    return Segments(points=pts, normals=nrm, mask=msk, labels=labels)
