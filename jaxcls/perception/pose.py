"""Initial poses for geometric refinement (the role DenseFusion plays in the paper; here depth alone).

An object stands upright on the table, so a model-to-world pose is a yaw about world z and a translation
whose z puts the model's base (its frame's z = 0) on the table. The translation comes from the segment's
centroid (the paper's choice), corrected for the model's own centroid offset: the model's sample centroid,
turned by the yaw, lands under the segment's centroid in xy. The yaw is not observed; two ways to guess it:

- (a) ``even_yaws``: H yaws evenly spread over a full turn; refinement keeps the one with the best rho;
- (b) ``learned_yaws``: around the classifier's yaw-head estimate (``pointnet.estimate_yaw``, known modulo
  2 pi / s for a class of symmetry order s): its s copies first, then further ones ``spread`` apart.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxcls.geometry import yaw_rotation
from jaxcls.math import safe_div


def initial_poses(points: jax.Array, mask: jax.Array, centroid: jax.Array, table_height: float | jax.Array,
                  yaws: jax.Array) -> jax.Array:
    """[H, 4, 4] model-to-world poses, one per yaw of ``yaws: [H]`` (rad).

    points: [P, 3] the segment's world points (m); mask: [P] bool; centroid: [3] the model's sample
    centroid in its own frame (m); table_height: world z of the table (m).
    """
    w = mask.astype(points.dtype)
    c = safe_div(jnp.sum(w[:, None] * points, axis=0), jnp.sum(w))
    H = yaws.shape[0]
    R = yaw_rotation(jnp.asarray(yaws, points.dtype))  # [H, 3, 3]
    t = jnp.concatenate([c[:2] - (R[:, :2, :2] @ centroid[:2]), jnp.full((H, 1), table_height, points.dtype)], axis=1)
    return jnp.zeros((H, 4, 4), points.dtype).at[:, :3, :3].set(R).at[:, :3, 3].set(t).at[:, 3, 3].set(1)


def even_yaws(hypotheses: int) -> jax.Array:
    """[H] yaws 2 pi h / H (rad): (a), no estimate."""
    return 2 * jnp.pi * jnp.arange(hypotheses, dtype=jnp.float32) / hypotheses


def learned_yaws(estimate: jax.Array, order: jax.Array, hypotheses: int, spread: float) -> jax.Array:
    """[H] yaws (rad) around a yaw estimate known modulo 2 pi / ``order`` (0 = continuous: any yaw, the
    estimate is 0). Hypothesis h is copy h mod s of the estimate (s = max(order, 1): estimate + 2 pi j / s)
    turned by ring h // s: 0, +spread, -spread, +2 spread, ... (H = 1: the estimate; H = 3 with s = 1:
    the estimate and one ``spread`` either side)."""
    s = jnp.maximum(order, 1)
    h = jnp.arange(hypotheses)
    ring = h // s
    offset = spread * ((ring + 1) // 2) * jnp.where(ring % 2 == 1, 1.0, -1.0)
    return (estimate + 2 * jnp.pi * (h % s) / s + offset).astype(jnp.float32)
