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
