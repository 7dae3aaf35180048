"""Initial poses for geometric refinement (the role DenseFusion plays in the paper; here depth alone).

An object stands upright on the table, so a model-to-world pose is a yaw about world z and a translation
whose z puts the model's base (its frame's z = 0) on the table. The translation comes from the segment's
centroid (the paper's choice), corrected for the model's own centroid offset: the model's sample centroid,
turned by the yaw, lands under the segment's centroid in xy. The yaw is not observed: ``initial_poses``
spreads ``hypotheses`` yaws evenly over a full turn (or over ``spread`` around a ``yaw`` estimate, such as
the one the classifier's yaw head gives), and refinement keeps the one with the best rho.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxcls.geometry import yaw_rotation
from jaxcls.math import safe_div


def initial_poses(points: jax.Array, mask: jax.Array, centroid: jax.Array, table_height: float | jax.Array,
                  hypotheses: int, yaw: jax.Array | float = 0.0, spread: float = 2 * jnp.pi) -> jax.Array:
    """[H, 4, 4] model-to-world poses, H = ``hypotheses``.

    points: [P, 3] the segment's world points (m); mask: [P] bool; centroid: [3] the model's sample
    centroid in its own frame (m); table_height: world z of the table (m). The yaws are ``yaw`` + ``spread``
    * (h / H) for a full turn (``spread`` = 2 pi, the default: evenly spaced, ``yaw`` the first), else
    evenly over [-spread/2, spread/2] around ``yaw`` (H = 1: ``yaw`` itself).
    """
    w = mask.astype(points.dtype)
    c = safe_div(jnp.sum(w[:, None] * points, axis=0), jnp.sum(w))
    h = jnp.arange(hypotheses, dtype=points.dtype)
    if spread >= 2 * jnp.pi:
        offsets = spread * h / hypotheses
    else:
        offsets = spread * (h / max(hypotheses - 1, 1) - 0.5) if hypotheses > 1 else h
    R = yaw_rotation(yaw + offsets)  # [H, 3, 3]
    t = jnp.concatenate([c[:2] - (R[:, :2, :2] @ centroid[:2]),
                         jnp.full((hypotheses, 1), table_height, points.dtype)], axis=1)
    return jnp.zeros((hypotheses, 4, 4), points.dtype).at[:, :3, :3].set(R).at[:, :3, 3].set(t).at[:, 3, 3].set(1)
