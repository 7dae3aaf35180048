"""Gradient-safe norms and divisions: the one place where a zero length or a zero denominator is handled; and the
weighted normal equations of a least-squares step (``normal_equations``).

``jnp.where(ok, x / y, 0)`` is not enough under autodiff: the branch not taken still runs, and a division
by zero there makes the gradient NaN. These functions put a safe value into the division itself (the
"double where"), so values and gradients stay finite at zero (see jax-ml/jax#1052).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxcls import precision

TINY = 1e-12


def safe_div(num: jax.Array, den: jax.Array, fallback: float | jax.Array = 0.0) -> jax.Array:
    """``num / den`` where ``|den| > 0``, else ``fallback``; finite gradients everywhere. Broadcasts."""
    ok = den != 0
    # ones_like, not 1.0: an integer ``den`` (a count) stays integer, and the quotient is a strong float32
    # (a Python 1.0 would make it weakly typed, and a jit fed it back would compile again).
    return jnp.where(ok, num / jnp.where(ok, den, jnp.ones_like(den)), fallback)


def safe_norm(x: jax.Array, axis: int = -1, keepdims: bool = False) -> jax.Array:
    """Euclidean norm of ``x: [..., D]`` along ``axis``; 0 (with a zero gradient) for a zero vector."""
    sq = jnp.sum(x * x, axis=axis, keepdims=True)
    ok = sq > 0
    norm = jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0)
    return norm if keepdims else jnp.squeeze(norm, axis=axis)


def normalize(x: jax.Array, axis: int = -1, eps: float = TINY) -> jax.Array:
    """``x / |x|`` along ``axis`` for vectors longer than ``eps``; 0 for shorter ones (never NaN)."""
    norm = safe_norm(x, axis=axis, keepdims=True)
    return jnp.where(norm > eps, x / jnp.where(norm > eps, norm, 1.0), 0.0)


def row_dots(x: jax.Array, M: jax.Array, fused: bool | None = None) -> jax.Array:
    """``x @ M.T``: the dot products [..., K] of points ``x: [..., 3]`` with the rows of ``M: [K, 3]``, at full
    float32 precision. On an accelerator as three products and two sums, which XLA fuses into the operations
    around them (a product of 3 terms is a kernel of its own on a GPU, its [..., K] output written out first); on
    the CPU the HIGHEST product itself (``geometry.rotate``, this with a rotation, says why; ``fused`` as there)."""
    if not precision.fused_products(fused):
        return jnp.einsum("ij,...j->...i", M, x, precision=jax.lax.Precision.HIGHEST)
    return x[..., 0:1] * M[:, 0] + x[..., 1:2] * M[:, 1] + x[..., 2:3] * M[:, 2]


def normal_equations(J: jax.Array, w: jax.Array, r: jax.Array, fused: bool | None = None
                     ) -> tuple[jax.Array, jax.Array]:
    """(J^T W J [K, K], J^T W r [K]) of residuals ``r: [P]`` with Jacobian ``J: [P, K]`` and weights ``w: [P]``,
    at full float32 precision. On an accelerator as products summed over P, which fuse with what makes J: with
    K of 4 or 6 a matrix product is a kernel of its own on a GPU, at HIGHEST precision a slow one (BENCHMARKS.md,
    issue 34); on the CPU the HIGHEST products themselves (``geometry.rotate`` says why; ``fused`` as there)."""
    Jw = J * w[:, None]
    if not precision.fused_products(fused):
        highest = jax.lax.Precision.HIGHEST
        return jnp.matmul(J.T, Jw, precision=highest), jnp.matmul(J.T, w * r, precision=highest)
    return jnp.sum(Jw[:, :, None] * J[:, None, :], axis=0), jnp.sum(Jw * r[:, None], axis=0)


def linear_sum_assignment(cost: jax.Array) -> jax.Array:
    """[n] i32 the column assigned to each row of ``cost: [n, m]`` (n <= m, finite) that minimises the total cost:
    what ``scipy.optimize.linear_sum_assignment`` gives (ties aside), jit- and vmap-able. The shortest augmenting
    path algorithm with dual potentials (Kuhn-Munkres as Jonker and Volgenant run it): a row at a time, O(n^2 m)."""
    n, m = cost.shape
    if n > m:
        raise ValueError(f"linear_sum_assignment: {n} rows and {m} columns; give n <= m (transpose the costs)")
    big = jnp.finfo(cost.dtype).max
    # Index 0 of the columns is a virtual one (1-based columns, as the algorithm's usual statement).
    padded = jnp.pad(cost, ((1, 0), (1, 0)))

    def add_row(i, carry):
        u, v, owner = carry  # owner [m + 1]: the row (1-based, 0 none) holding each column

        def grow(search):
            u, v, owner, way, minv, used, j0 = search
            used = used.at[j0].set(True)
            i0 = owner[j0]
            reduced = padded[i0] - u[i0] - v  # [m + 1]
            better = ~used & (reduced < minv)
            minv = jnp.where(better, reduced, minv)
            way = jnp.where(better, j0, way)
            free = jnp.where(used, big, minv).at[0].set(big)
            j1 = jnp.argmin(free)
            delta = free[j1]
            u = u.at[jnp.where(used, owner, 0)].add(jnp.where(used, delta, 0.0))
            v = jnp.where(used, v - delta, v)
            minv = jnp.where(used, minv, minv - delta)
            return u, v, owner, way, minv, used, j1

        search = (u, v, owner.at[0].set(i), jnp.zeros(m + 1, jnp.int32), jnp.full(m + 1, big, cost.dtype),
                  jnp.zeros(m + 1, bool), jnp.int32(0))
        u, v, owner, way, _, _, j0 = jax.lax.while_loop(lambda s: s[2][s[6]] != 0, grow, grow(search))

        def augment(state):
            owner, j0 = state
            j1 = way[j0]
            return owner.at[j0].set(owner[j1]), j1

        owner, _ = jax.lax.while_loop(lambda s: s[1] != 0, augment, (owner, j0))
        return u, v, owner

    zeros = jnp.zeros(n + 1, cost.dtype), jnp.zeros(m + 1, cost.dtype)
    _, _, owner = jax.lax.fori_loop(1, n + 1, add_row, (*zeros, jnp.zeros(m + 1, jnp.int32)))
    # row of each column -> column of each row
    return jnp.zeros(n + 1, jnp.int32).at[owner[1:]].set(jnp.arange(1, m + 1, dtype=jnp.int32))[1:] - 1
