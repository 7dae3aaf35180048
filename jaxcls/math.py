"""Gradient-safe norms and divisions: the one place where a zero length or a zero denominator is handled.

``jnp.where(ok, x / y, 0)`` is not enough under autodiff: the branch not taken still runs, and a division
by zero there makes the gradient NaN. These functions put a safe value into the division itself (the
"double where"), so values and gradients stay finite at zero (see jax-ml/jax#1052).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

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
