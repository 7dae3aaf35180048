"""Backend ``mjx``: MJX's pure-JAX ray caster (``mujoco.mjx.ray``), jitted, chunked over rays.

``mjx.ray`` intersects one ray with every geom; meshes cost one test per face (O(rays x faces)). A plain
vmap over a 640x480 frame asks for tens of GB, so rays go through ``lax.map`` in vmapped chunks.
Like the C caster it returns the ray parameter of ``pnt + x * vec``: with camera-frame directions of z = 1
(``geometry.pixel_rays``) that is the z-depth.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxcls.geometry import Intrinsics, pixel_rays
from jaxcls.world.render import contract
from jaxcls.world.render.mjx_quiet import mjx
from jaxcls.world.render.types import NO_DEPTH, NO_OBJECT, Backend, DepthFrames

# Intermediate floats of one chunk stay near this budget: about 32 floats per (ray, triangle) pair.
_CHUNK_PAIRS = 1 << 22


def default_chunk(model: mujoco.MjModel) -> int:
    """Rays per vmapped chunk so that rays x mesh faces stays near ``_CHUNK_PAIRS``; 256..16384."""
    faces = int(np.sum(model.mesh_facenum)) if model.nmesh else 0
    return int(np.clip(_CHUNK_PAIRS // max(faces, 1), 256, 16384))


def cast_rays(mx: mjx.Model, dx: mjx.Data, geom_object: jax.Array, origins: jax.Array, dirs: jax.Array,
              chunk: int) -> tuple[jax.Array, jax.Array]:
    """Ray parameter and object id of the first rendered geom hit along each ray.

    geom_object: [ngeom] i32 object index of each geom (-1 table). origins, dirs: [R, 3] world frame.
    Returns depth [R] f32 (0 = no hit) and object_id [R] i32 (-1 = table or no hit).
    """

    def one(ray):
        pnt, vec = ray
        dist, geom = mjx.ray(mx, dx, pnt, vec, geomgroup=contract.GEOMGROUP_MASK, flg_static=True)
        hit = geom >= 0
        return (jnp.where(hit, dist, NO_DEPTH).astype(jnp.float32),
                jnp.where(hit, geom_object[jnp.maximum(geom, 0)], NO_OBJECT).astype(jnp.int32))

    return jax.lax.map(one, (origins, dirs), batch_size=chunk)


def render_depth(mx: mjx.Model, dx: mjx.Data, geom_object: jax.Array, T_wc: jax.Array,
                 intrinsics: Intrinsics, chunk: int) -> DepthFrames:
    """Frames seen from ``T_wc: [B, 4, 4]`` (OpenCV camera-to-world, metres). Pure in T_wc; jit with
    ``intrinsics`` and ``chunk`` static. All B x H x W rays share one chunked map, so memory is set by
    ``chunk`` alone."""
    B, H, W = T_wc.shape[0], intrinsics.height, intrinsics.width
    # GPUs default to TF32 matmuls (10-bit mantissa): millimetres at a metre, here and inside mjx.ray.
    with jax.default_matmul_precision("highest"):
        rays = jnp.asarray(pixel_rays(intrinsics).reshape(-1, 3), T_wc.dtype)  # [N, 3], z = 1
        dirs = jnp.einsum("bij,nj->bni", T_wc[:, :3, :3], rays).reshape(-1, 3)
        origins = jnp.broadcast_to(T_wc[:, None, :3, 3], (B, H * W, 3)).reshape(-1, 3)
        depth, object_id = cast_rays(mx, dx, geom_object, origins, dirs, chunk)
    return DepthFrames(depth=depth.reshape(B, H, W), object_id=object_id.reshape(B, H, W))


def put_scene(model: mujoco.MjModel) -> tuple[mjx.Model, mjx.Data, jax.Array]:
    """(mjx model, data with geom poses set, [ngeom] geom->object map) of a render copy of ``model``."""
    mjm = contract.render_model(model)
    data = mujoco.MjData(mjm)
    mujoco.mj_forward(mjm, data)  # host kinematics: mjx.kinematics refuses models without DoFs
    device = jax.local_devices()[0]  # (MJX's default, the first global device, is process 0's)
    mx = mjx.put_model(mjm, impl="jax", device=device)
    dx = mjx.put_data(mjm, data, impl="jax", device=device)
    return mx, dx, jnp.asarray(contract.object_ids_of_geoms(mjm))


class MJXRenderer:
    """``render_depth`` behind the host-side checks of the Renderer protocol."""

    backend: Backend = Backend.mjx

    def __init__(self, model: mujoco.MjModel, intrinsics: Intrinsics, chunk: int | None = None):
        if chunk is not None and chunk < 1:
            raise ValueError(f"chunk must be >= 1, got {chunk}")
        self.intrinsics = intrinsics
        self.chunk = chunk or default_chunk(model)
        self._mx, self._dx, self._geom_object = put_scene(model)
        self._render = jax.jit(functools.partial(render_depth, intrinsics=intrinsics, chunk=self.chunk))

    def render(self, T_wc: np.ndarray) -> DepthFrames:
        """T_wc: [B, 4, 4] | [4, 4]. Returns JAX [B, H, W] f32 depth and i32 object ids."""
        T = jnp.asarray(contract.check_poses(T_wc), jnp.float32)
        return self._render(self._mx, self._dx, self._geom_object, T)

    def depth_fn(self, batch: int):
        """A traceable ``T_wc [batch, 4, 4] -> depth [batch, H, W]`` (m, 0 = no return): the frames of ``render``
        inside a caller's jit (an episode that renders as it moves, ``episode.batched.rendered``); no host-side
        checks on the poses."""
        del batch  # the rays of any batch share one chunked map

        def depth(T_wc: jax.Array) -> jax.Array:
            return render_depth(self._mx, self._dx, self._geom_object, T_wc.astype(jnp.float32), self.intrinsics,
                                self.chunk).depth

        return depth
