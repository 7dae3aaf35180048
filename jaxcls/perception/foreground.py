"""Foreground: which depth pixels and surface points belong to objects (paper Sec. 3.1: truncate depth,
remove the table plane, keep the cube of interest).

Conventions (docs/ARCHITECTURE.md): metres, world z up, table top at ``spec.table_height``; OpenCV camera,
``T_wc`` camera-to-world; depth z-depth with 0 = no return. Point sets are padded: ``points [P, 3]`` +
``mask [P]``.

Bad depth pixels, the rule: a depth pixel that is NaN, +-inf or negative (or 0) is "no return". Perception
masks such pixels (``valid_depth``) in every stage that reads the frame (the camera tracking's
registration, ``foreground_depth``, TSDF integration), so a frame with them gives exactly the observation
the same frame with those pixels 0 gives, under jit too, and nothing NaN comes out of a move. The sources
of frames on the host refuse them instead, naming the file and the view (a dataset scene file:
``world.dataset.check_views``), and a recording stores them as 0 with a warning
(``world.recording.depth_to_raw``): a NaN in a file is a writer's mistake worth hearing about, a NaN in
a live sensor's frame is a pixel without a return.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import geometry
from jaxcls.perception.settings import Spec


def check_depth_shape(spec: Spec, depth: jax.Array, T_wc: jax.Array, where: str) -> None:
    """Raise ValueError naming the shapes unless depth is [H, W] of the spec's camera and T_wc is [4, 4]
    (trace time: shapes are static, so this runs under jit too)."""
    expected = (spec.intrinsics.height, spec.intrinsics.width)
    if tuple(np.shape(depth)) != expected:
        raise ValueError(f"{where}: depth has shape {tuple(np.shape(depth))}, the camera expects [H, W] = "
                         f"{list(expected)}")
    if tuple(np.shape(T_wc)) != (4, 4):
        raise ValueError(f"{where}: T_wc must be [4, 4], got shape {tuple(np.shape(T_wc))}")


def valid_depth(depth: jax.Array) -> jax.Array:
    """[H, W] bool: the pixels of ``depth: [H, W]`` m that hold a return (finite and > 0); the rest (0, NaN,
    inf, negative) are "no return" (the module's rule). Pure jnp."""
    return jnp.isfinite(depth) & (depth > 0)


@jax.jit
def foreground_depth(spec: Spec, depth: jax.Array, T_wc: jax.Array) -> jax.Array:
    """Depth with background and table pixels set to 0 (no return), before fusion.

    depth: [H, W] z-depth, m (0, NaN, inf, negative = no return); T_wc: [4, 4] camera-to-world.
    Zeroes pixels beyond ``foreground.max_depth`` and pixels whose world point has z <= ``spec.floor``
    (table height + table_eps). Returns [H, W] f32, never NaN.
    """
    check_depth_shape(spec, depth, T_wc, "foreground_depth")
    intrinsics = spec.intrinsics
    depth = jnp.asarray(depth, jnp.float32)
    good = valid_depth(depth) & (depth <= spec.config.foreground.max_depth)
    depth = jnp.where(good, depth, 0.0)
    # World height of each pixel's point (only the third row of the back-projection: 3x less work).
    T_wc = jnp.asarray(T_wc, jnp.float32)
    rays = np.asarray(geometry.pixel_rays(intrinsics), np.float32)  # [H, W, 3]
    z = depth * jnp.einsum("hwj,j->hw", rays, T_wc[2, :3]) + T_wc[2, 3]
    return jnp.where(good & (z > spec.floor), depth, 0.0)


def foreground_mask(spec: Spec, points: jax.Array, mask: jax.Array) -> jax.Array:
    """[P] bool: ``mask`` and finite and above the table and inside the cube of interest.

    points: [P, 3] m; mask: [P] bool. Pure jnp, usable inside jit.
    """
    check_cloud_shape(points, mask, "foreground_mask")
    points = jnp.asarray(points)
    finite = jnp.all(jnp.isfinite(points), axis=-1)
    centre = jnp.asarray(spec.roi_center, points.dtype)
    inside = jnp.all(jnp.abs(points - centre) <= 0.5 * spec.roi_size, axis=-1)
    above = points[:, 2] > spec.floor
    return jnp.asarray(mask) & finite & inside & above


def check_cloud_shape(points: jax.Array, mask: jax.Array, where: str, normals: jax.Array | None = None) -> None:
    """Raise ValueError naming the shapes unless points (and normals) are [P, 3] and mask is [P]."""
    P = np.shape(points)[0] if np.ndim(points) == 2 else None
    if np.ndim(points) != 2 or np.shape(points)[1] != 3:
        raise ValueError(f"{where}: points must be [P, 3], got shape {tuple(np.shape(points))}")
    if normals is not None and tuple(np.shape(normals)) != (P, 3):
        raise ValueError(f"{where}: normals must be [P, 3] = {[P, 3]} like the points, got shape "
                         f"{tuple(np.shape(normals))}")
    if tuple(np.shape(mask)) != (P,):
        raise ValueError(f"{where}: mask must be [P] = [{P}] like the points, got shape {tuple(np.shape(mask))}")


@functools.partial(jax.jit, static_argnames=("max_points",))
def single_view_points(spec: Spec, depth: jax.Array, T_wc: jax.Array, max_points: int
                       ) -> tuple[jax.Array, jax.Array]:
    """One frame's foreground cloud without fusion (the paper's PointNetSingle input).

    depth: [H, W] m; T_wc: [4, 4]. Returns (points [max_points, 3] m, mask [max_points] bool): the
    foreground pixels' world points, evenly strided when there are more than ``max_points``.
    """
    fg = foreground_depth(spec, depth, T_wc)
    pts = geometry.backproject(fg, spec.intrinsics, jnp.asarray(T_wc, jnp.float32)).reshape(-1, 3)
    valid = foreground_mask(spec, pts, (fg > 0).reshape(-1))
    return compact(pts, valid, max_points)


def strided_slots(rank: jax.Array, count: jax.Array, size: int) -> tuple[jax.Array, jax.Array]:
    """Slot of each row among ``size`` slots, and whether it is kept: all rows when ``count <= size``, else
    ``size`` of them evenly strided in order. rank: [M] i32 rank of the row in its set; count: size of its
    set ([M] or scalar). Returns ([M] i32 slot, [M] bool keep: the first row of each slot)."""
    stride = jnp.maximum(count.astype(jnp.float32) / size, 1.0)
    slot = jnp.floor(rank.astype(jnp.float32) / stride).astype(jnp.int32)
    keep = (rank == jnp.ceil(slot.astype(jnp.float32) * stride).astype(jnp.int32)) & (slot < size)
    return slot, keep


def compact(points: jax.Array, valid: jax.Array, size: int) -> tuple[jax.Array, jax.Array]:
    """([size, 3], [size]) the valid rows of ``points: [M, 3]``, evenly strided if more than ``size``."""
    slot, keep = strided_slots(jnp.cumsum(valid) - 1, jnp.sum(valid), size)
    keep &= valid
    target = jnp.where(keep, slot, size)  # out of bounds: dropped
    out = jnp.zeros((size, 3), points.dtype).at[target].set(points, mode="drop")
    mask = jnp.zeros(size, bool).at[target].set(True, mode="drop")
    return out, mask
