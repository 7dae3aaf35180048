"""Grid operations in JAX on the footprint grid ``[G, G]``: shifts, 3x3 morphology, connected components,
hole filling, the exact distance transform, Gaussian blur, nearest seeds (each tested against SciPy)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls.perception.segment.common import _gaussian_kernel


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


class _Propagation(NamedTuple):
    """Label propagation's loop state: parent [G * G] i32 each cell's label, changed [] bool, rounds [] i32."""

    parent: jax.Array
    changed: jax.Array
    rounds: jax.Array


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

    def step(state: _Propagation) -> _Propagation:
        parent = state.parent
        rep = jnp.where(occ, parent.reshape(G, G), -1)
        nb = rep
        for di, dj in neighbours:
            nb = jnp.maximum(nb, _shifted(rep, di, dj, -1))
        target = jnp.where(occ_flat, rep.reshape(-1), G * G)  # out of bounds: dropped
        new = parent.at[target].max(nb.reshape(-1), mode="drop")
        for _ in range(4):
            new = new[new]
        return _Propagation(new, jnp.any(new != parent), state.rounds + 1)

    start = _Propagation(parent, jnp.array(True), jnp.int32(0))
    parent = jax.lax.while_loop(lambda s: s.changed & (s.rounds < max_iters), step, start).parent
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
