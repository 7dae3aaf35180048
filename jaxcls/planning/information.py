"""Volumetric information gain of candidate views on the TSDF (beyond the paper; the Delmerico et al. 2018
family): how much of the space of interest a view would observe for the first time.

Rays from each candidate camera (a coarse grid of the sensor's pixels, ``rays_scale``) are marched through
the volume's cube in steps of ``step_voxels`` voxels; a sample counts when its voxel is unobserved (weight 0)
and no observed surface (an observed voxel behind the zero crossing, tsdf < 0) lies before it on the ray.

Shapes: volume ``tsdf.TSDFVolume`` ([X, Y, Z]); T_wc [V, 4, 4]; returns [V] f32 unobserved samples per view.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls.config import bounded, check_bounds
from jaxcls.geometry import Intrinsics, pixel_rays
from jaxcls.math import safe_div
from jaxcls.perception.tsdf import TSDFVolume
from jaxcls.planning.visibility import scaled

HIGHEST = jax.lax.Precision.HIGHEST


@dataclasses.dataclass(frozen=True)
class GainConfig:
    """Ray grid and marching step of the information gain."""

    rays_scale: float = bounded(0.0625, gt=0.0, le=1.0)  # of the sensor's resolution (40 x 30 rays for 640 x 480)
    step_voxels: float = bounded(2.0, gt=0.0)  # marching step, in voxels

    def __post_init__(self) -> None:
        check_bounds(self, "gain.")


def gain(volume: TSDFVolume, T_wc: jax.Array, intrinsics: Intrinsics, config: GainConfig = GainConfig()) -> jax.Array:
    """[V] f32: the unobserved samples each candidate view's rays would reach (see the module docstring)."""
    rays = pixel_rays(scaled(intrinsics, config.rays_scale)).reshape(-1, 3)
    rays = jnp.asarray(rays / np.linalg.norm(rays, axis=-1, keepdims=True), jnp.float32)  # unit: t in metres
    shape = jnp.array(volume.tsdf.shape)
    lo = volume.origin - 0.5 * volume.voxel_size
    hi = lo + shape * volume.voxel_size
    step = config.step_voxels * volume.voxel_size
    steps = math.ceil(math.sqrt(3) * max(volume.tsdf.shape) / config.step_voxels) + 1
    k = jnp.arange(steps, dtype=jnp.float32)

    def one_view(T):
        origin, d = T[:3, 3], jnp.einsum("ij,rj->ri", T[:3, :3], rays, precision=HIGHEST)
        inv = safe_div(1.0, d, fallback=jnp.inf)
        t0, t1 = (lo - origin) * inv, (hi - origin) * inv
        enter = jnp.maximum(jnp.max(jnp.minimum(t0, t1), axis=1), 0.0)
        leave = jnp.min(jnp.maximum(t0, t1), axis=1)
        t = enter[:, None] + (k[None, :] + 0.5) * step  # [R, S]
        inside = t < leave[:, None]
        x = origin + t[..., None] * d[:, None, :]
        idx = jnp.clip(jnp.floor((x - lo) / volume.voxel_size).astype(jnp.int32), 0, shape - 1)
        w = volume.weight[idx[..., 0], idx[..., 1], idx[..., 2]]
        f = volume.storage.decode(volume.tsdf[idx[..., 0], idx[..., 1], idx[..., 2]])
        surface = inside & (w > 0) & (f < 0)
        before_surface = jnp.cumsum(surface, axis=1) == 0
        return jnp.sum(inside & (w == 0) & before_surface).astype(jnp.float32)

    return jax.vmap(one_view)(jnp.asarray(T_wc, jnp.float32))


gain_jit = jax.jit(gain, static_argnames=("intrinsics", "config"))
