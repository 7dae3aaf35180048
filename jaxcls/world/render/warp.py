"""Backend ``warp``: MJX's batch ray-traced renderer on MuJoCo Warp (CUDA GPU only).

One world per view: the camera and the geoms are posed per world, ``mjx.refit_bvh`` and
``mjx.render_with_segmentation`` trace depth and segmentation for all worlds. Two ways to pose them:
- ``kinematics="static"`` (the scene bank's): no MuJoCo kinematics on the GPU. The camera frame is written from the
  pose, and every geom is its host rest pose carried rigidly by the mocap body that holds it (``GeomRig``,
  ``posed_geoms``: one product in JAX; a scene bank's objects are mocap bodies). Models without joints only
  (the scene contract has none).
- ``kinematics="forward"`` (the default): the camera's mocap body is posed and ``mjx.forward`` moves everything,
  collision detection and constraints included (over a scene bank's parked meshes, which all overlap). The
  reference the static path is checked against.
(On an H100 at 640x480, B = 512, one scene's model: static 12.8k frames/s, forward 10.7k, each in its graph mode
below; a real-like scene bank on an H200, B = 1,024: 12.7k and 12.1k, both agreeing with MuJoCo's C caster on
every pixel within 1 mm: BENCHMARKS.md. The two differ from each other in the last bits of some depths, enough
to move a few of Table 1's records: F1 within 0.004 of each other, row by row.)
What the installed MuJoCo Warp renderer (``mjx/third_party/mujoco_warp/_src/render.py``) writes:
- depth: planar z-depth ``dist * cos(ray, optical axis)`` in metres, 0 where the ray hits nothing, and 0
  past ``zfar = vis.map.zfar * stat.extent``. Rays start at the camera centre (no near clip).
- segmentation: per pixel ``(id, type)``: ``(geom_id, mjOBJ_GEOM)`` for geoms, ``(flex_id, mjOBJ_FLEX)``
  for flexes, ``(-1, -1)`` for background.
- pixel (u, v) of a W x H camera looks through ((u + 0.5) / W, (v + 0.5) / H) of a centred fovy
  frustum, row 0 at the top: ``Intrinsics.from_fovy`` of the same size, hence the fovy check.
``mjx.get_depth`` would clip to ``[0, 1]`` after dividing by a scale; we slice the raw buffers ourselves
(``unpack_frames``, pure and CPU-testable), which keeps metres exactly and needs no scale.

The GPU-only code is ``WarpRenderer``, ``posed_data_forward`` and ``render_buffers``; the rest runs on
a CPU (``posed_geoms`` is checked there against MuJoCo's own kinematics). Every JAX matmul here asks for full
float32: GPUs default to TF32, whose 10-bit mantissa moved the camera by millimetres (95.6% of pixels within
1 mm of ``mujoco`` instead of 100%).
"""

from __future__ import annotations

import os
import re
from typing import Any, Literal

import jax
import jax.numpy as jnp
import jaxlie
import mujoco
import numpy as np
from flax import struct

from jaxcls.geometry import CV_TO_MJ, Intrinsics
from jaxcls.math import normalize
from jaxcls.world.render import contract
from jaxcls.world.render.factory import loads_beside_renders
from jaxcls.world.render.mjx_quiet import mjx, mjxw
from jaxcls.world.render.types import NO_DEPTH, NO_OBJECT, Backend, DepthFrames

INSTALL_HINT = ("The warp backend needs a CUDA GPU visible to JAX (jax[cuda]) and warp-lang at the "
                "version MJX pins: pip install 'mujoco-mjx[warp]' (MuJoCo Warp itself ships inside "
                "mujoco-mjx). Use backend='mujoco' or 'mjx' on a CPU.")

_GEOM_TYPE = int(mujoco.mjtObj.mjOBJ_GEOM)


def warp_unavailable_reason() -> str | None:
    """Why the warp backend cannot run here, or None when a CUDA GPU and warp-lang are present."""
    if not mjxw.WARP_INSTALLED:
        return "warp-lang is not installed"
    try:
        if not jax.devices("cuda"):
            return "JAX sees no CUDA device"
    except RuntimeError:
        return "JAX has no CUDA backend"
    return None


def render_device() -> jax.Device:
    """The GPU that renders: this process's first local CUDA device (Warp's ``cuda:0``). MJX's own default is
    the first *global* CUDA device, which under ``jax.distributed`` belongs to process 0: a model put there
    from another process could not run ("executable expects 0 computations")."""
    return jax.local_devices(backend="cuda")[0]


# ---------------------------------------------------------------- pure parts (CPU-testable)

def out_of_memory_message(batch: int, intrinsics: Intrinsics, error: Exception) -> str:
    """What to do when Warp cannot allocate a render context of ``batch`` worlds (``error``: Warp's
    "Failed to allocate N bytes"): its buffers live outside JAX's memory pool, which by default takes 75% of
    the GPU (``XLA_PYTHON_CLIENT_MEM_FRACTION``), so a large batch needs that fraction lowered or fewer worlds."""
    fraction = os.environ.get("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.75 (JAX's default)")
    preallocate = os.environ.get("XLA_PYTHON_CLIENT_PREALLOCATE", "true")
    return (f"backend 'warp': MuJoCo Warp could not allocate the render buffers of {batch} worlds at "
            f"{intrinsics.width}x{intrinsics.height} ({error}). Warp allocates outside JAX's memory pool, which "
            f"holds XLA_PYTHON_CLIENT_MEM_FRACTION = {fraction} of the GPU (XLA_PYTHON_CLIENT_PREALLOCATE = "
            f"{preallocate}): lower the fraction (e.g. 0.66 for 4,096 worlds at 640x480 on an 80 GB GPU, "
            "BENCHMARKS.md) or render fewer worlds at once")


@struct.dataclass
class BufferLayout:
    """Where the one camera's pixels sit in MJX's packed per-world render buffers (all static)."""

    depth_adr: int = struct.field(pytree_node=False)
    seg_adr: int = struct.field(pytree_node=False)
    width: int = struct.field(pytree_node=False)
    height: int = struct.field(pytree_node=False)


def unpack_frames(depth_buf: jax.Array, seg_buf: jax.Array, layout: BufferLayout,
                  geom_object: jax.Array) -> DepthFrames:
    """Our frames from MJX's packed buffers.

    depth_buf: [B, P] f32 planar depth in metres (0 = miss); seg_buf: [B, P', 2] i32 (id, mjtObj type),
    (-1, -1) for background; geom_object: [ngeom] i32 object index per geom (-1 table).
    Returns [B, H, W] f32 depth (0 where no geom was hit or the value is not a positive finite number)
    and i32 object ids (-1 for the table, flexes, misses and wherever depth is 0).
    """
    n = layout.width * layout.height
    shape = (depth_buf.shape[0], layout.height, layout.width)
    depth = jax.lax.slice_in_dim(depth_buf, layout.depth_adr, layout.depth_adr + n, axis=1).reshape(shape)
    seg = jax.lax.slice_in_dim(seg_buf, layout.seg_adr, layout.seg_adr + n, axis=1).reshape(*shape, 2)
    geom, kind = seg[..., 0], seg[..., 1]
    hit = (kind == _GEOM_TYPE) & (geom >= 0) & (geom < geom_object.shape[0])
    valid = hit & jnp.isfinite(depth) & (depth > 0)
    object_id = jnp.where(valid, geom_object[jnp.clip(geom, 0, geom_object.shape[0] - 1)], NO_OBJECT)
    return DepthFrames(depth=jnp.where(valid, depth, NO_DEPTH).astype(jnp.float32),
                       object_id=object_id.astype(jnp.int32))


def camera_in_body(model: mujoco.MjModel, cam: int) -> np.ndarray:
    """[4, 4] pose of MuJoCo camera ``cam`` in its body's frame (identity under the scene contract)."""
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, np.asarray(model.cam_quat[cam], float))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R.reshape(3, 3), model.cam_pos[cam]
    return T


def mocap_poses(T_wc: jax.Array, T_body_cam: np.ndarray) -> tuple[jax.Array, jax.Array]:
    """Mocap (pos [B, 3], quat [B, 4] w x y z) that put a MuJoCo camera mounted at ``T_body_cam`` (its
    body frame) where the OpenCV camera ``T_wc: [B, 4, 4]`` is. Pure JAX, so it traces under jit."""
    cv_to_mj = np.eye(4)
    cv_to_mj[:3, :3] = CV_TO_MJ
    T_cam_body = jnp.asarray(cv_to_mj @ np.linalg.inv(T_body_cam), T_wc.dtype)
    # full f32 matmul: GPUs default to TF32, whose 10-bit mantissa moves the camera by millimetres
    T_wb = jnp.matmul(T_wc, T_cam_body, precision=jax.lax.Precision.HIGHEST)
    return T_wb[:, :3, 3], quat_from_matrix(T_wb[:, :3, :3])


def quat_from_matrix(R: jax.Array) -> jax.Array:
    """[..., 4] unit quaternions (w, x, y, z), w >= 0, of rotations ``R: [..., 3, 3]``.

    ``jaxlie.SO3.from_matrix`` (branch-free: every square root sees at least 1), with MuJoCo's sign and
    the norm of float32 rounding taken out.
    """
    q = jaxlie.SO3.from_matrix(R).wxyz
    return normalize(q * jnp.where(q[..., :1] < 0, -1.0, 1.0))


@struct.dataclass
class GeomRig:
    """Every geom as a rigid offset from the mocap body that moves it, for a model without joints.

    rest_pos: [G, 3] m and rest_mat: [G, 3, 3] each geom's world pose at rest (the host's ``mj_kinematics``);
    mocap: [G] i32 the mocap index of the body carrying the geom (its own body or the nearest mocap ancestor),
    -1 for geoms that nothing moves (the table, the world's); offset_pos: [G, 3] m and offset_mat: [G, 3, 3] the
    geom's pose in that mocap body's frame (its rest pose where ``mocap`` is -1).
    """

    rest_pos: jax.Array
    rest_mat: jax.Array
    mocap: jax.Array
    offset_pos: jax.Array
    offset_mat: jax.Array


def geom_rig(model: mujoco.MjModel) -> GeomRig:
    """``model``'s ``GeomRig``; raises for a model with joints (its geoms are not rigid offsets of mocap
    bodies: render it with ``kinematics='forward'``)."""
    if model.njnt:
        raise ValueError(f"warp: kinematics 'static' poses geoms rigidly with their mocap bodies, but the model "
                         f"has {model.njnt} joints: use kinematics='forward'")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)  # (the rest poses; no collision among the parked slots)
    carrier = np.zeros(model.ngeom, np.int64)  # the body that moves each geom (0: the world, nothing moves it)
    for g in range(model.ngeom):
        b = int(model.geom_bodyid[g])
        while b != 0 and model.body_mocapid[b] < 0:
            b = int(model.body_parentid[b])
        carrier[g] = b
    rest_mat = data.geom_xmat.reshape(-1, 3, 3)
    body_mat = data.xmat.reshape(-1, 3, 3)[carrier]  # [G, 3, 3] the carrier's rest frame (float64)
    offset_mat = np.einsum("gji,gjk->gik", body_mat, rest_mat)
    offset_pos = np.einsum("gji,gj->gi", body_mat, data.geom_xpos - data.xpos[carrier])
    moved = carrier != 0
    return GeomRig(rest_pos=jnp.asarray(data.geom_xpos, jnp.float32), rest_mat=jnp.asarray(rest_mat, jnp.float32),
                   mocap=jnp.asarray(np.where(moved, model.body_mocapid[carrier], -1), jnp.int32),
                   offset_pos=jnp.asarray(np.where(moved[:, None], offset_pos, data.geom_xpos), jnp.float32),
                   offset_mat=jnp.asarray(np.where(moved[:, None, None], offset_mat, rest_mat), jnp.float32))


def posed_geoms(rig: GeomRig, mocap_pos: jax.Array, mocap_quat: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Every geom's world pose with the mocap bodies at ``mocap_pos: [B, nmocap, 3]`` m and ``mocap_quat: [B,
    nmocap, 4]`` (w, x, y, z; normalised here, and a zero one the identity, as MuJoCo does): (xpos [B, G, 3] m,
    xmat [B, G, 3, 3]), what MuJoCo's kinematics gives a model without joints. Pure JAX, full float32 products."""
    q = mocap_quat.astype(jnp.float32)
    norm = jnp.linalg.norm(q, axis=-1, keepdims=True)
    q = jnp.where(norm < 1e-10, jnp.array([1.0, 0.0, 0.0, 0.0]), q / jnp.maximum(norm, 1e-10))  # (MuJoCo: 0 -> 1)
    R = jaxlie.SO3(q).as_matrix()  # [B, nmocap, 3, 3]
    at = jnp.maximum(rig.mocap, 0)
    R_g, p_g = R[:, at], mocap_pos.astype(jnp.float32)[:, at]  # [B, G, 3, 3], [B, G, 3]
    highest = jax.lax.Precision.HIGHEST
    xmat = jnp.matmul(R_g, rig.offset_mat, precision=highest)
    xpos = p_g + jnp.einsum("bgij,gj->bgi", R_g, rig.offset_pos, precision=highest)
    moved = rig.mocap >= 0
    return (jnp.where(moved[:, None], xpos, rig.rest_pos), jnp.where(moved[:, None, None], xmat, rig.rest_mat))


# ---------------------------------------------------------------- GPU parts

def posed_data_forward(mx: Any, dx0: Any, T_wc: jax.Array, T_body_cam: np.ndarray, mocap_id: int,
                       mocap_pos: jax.Array | None = None, mocap_quat: jax.Array | None = None) -> Any:
    """[B]-batched data with the camera's mocap body at ``T_wc: [B, 4, 4]``, moved by ``mjx.forward``. With
    ``mocap_pos: [B, nmocap, 3]`` and ``mocap_quat: [B, nmocap, 4]`` every other mocap body of each world is
    posed too (a scene bank's objects, ``world.bank``)."""
    pos, quat = mocap_poses(T_wc, T_body_cam)
    B = T_wc.shape[0]
    if mocap_pos is None:
        mocap_pos = jnp.broadcast_to(dx0.mocap_pos, (B, *dx0.mocap_pos.shape))
        mocap_quat = jnp.broadcast_to(dx0.mocap_quat, (B, *dx0.mocap_quat.shape))

    def pose_world(p: jax.Array, q: jax.Array, all_p: jax.Array, all_q: jax.Array) -> Any:
        d = dx0.replace(mocap_pos=all_p.at[mocap_id].set(p), mocap_quat=all_q.at[mocap_id].set(q))
        return mjx.forward(mx, d)  # kinematics + camlight: moves cam_xpos / cam_xmat (and the mocap geoms)

    return jax.vmap(pose_world)(pos.astype(jnp.float32), quat.astype(jnp.float32),
                                jnp.asarray(mocap_pos, jnp.float32), jnp.asarray(mocap_quat, jnp.float32))


def posed_data_static(dx0: Any, T_wc: jax.Array, geom_xpos: jax.Array, geom_xmat: jax.Array, cam_id: int) -> Any:
    """[B]-batched data with the geoms at ``geom_xpos: [G, 3] | [B, G, 3]`` m, ``geom_xmat: [G, 3, 3] | [B, G, 3,
    3]`` (one pose for every world, or one a world: ``posed_geoms``) and the camera frame written straight from
    ``T_wc: [B, 4, 4]``. Skips ``mjx.forward``."""
    cv_to_mj = jnp.asarray(CV_TO_MJ, jnp.float32)
    batched = geom_xpos.ndim == 3

    def pose_world(T: jax.Array, gx: jax.Array, gm: jax.Array) -> Any:
        R = jnp.matmul(T[:3, :3], cv_to_mj, precision=jax.lax.Precision.HIGHEST)
        return dx0.replace(geom_xpos=gx, geom_xmat=gm,
                           cam_xpos=dx0.cam_xpos.at[cam_id].set(T[:3, 3]), cam_xmat=dx0.cam_xmat.at[cam_id].set(R))

    axes = (0, 0, 0) if batched else (0, None, None)
    return jax.vmap(pose_world, in_axes=axes)(T_wc.astype(jnp.float32), geom_xpos.astype(jnp.float32),
                                              geom_xmat.astype(jnp.float32))


def render_buffers(mx: Any, dx: Any, rc: Any) -> tuple[jax.Array, jax.Array]:
    """Packed (depth [B, P], seg [B, P', 2]) buffers of the [B]-batched posed data ``dx``, one world each.

    rc: the render context's pytree, made for nworld = B.
    """
    dx = mjx.refit_bvh(mx, dx, rc)
    _, depth, seg, _ = mjx.render_with_segmentation(mx, dx, rc)
    return depth, seg


class WarpRenderer:
    """Batched GPU rendering; one render context (and compiled function) per batch size, cached."""

    backend: Backend = Backend.warp

    def __init__(self, model: mujoco.MjModel, intrinsics: Intrinsics,
                 kinematics: Literal["forward", "static"] = "forward"):
        reason = warp_unavailable_reason()
        if reason is not None:
            raise RuntimeError(f"backend 'warp' is unavailable: {reason}. {INSTALL_HINT}")
        contract.check_camera_matches(model, intrinsics)
        self.intrinsics = intrinsics
        self._mjm = contract.render_model(model)
        self._cam, self._mocap = contract.depth_camera(self._mjm)
        self._T_body_cam = camera_in_body(self._mjm, self._cam)
        self._geom_object = jnp.asarray(contract.object_ids_of_geoms(self._mjm))
        if kinematics not in ("forward", "static"):
            raise ValueError(f"kinematics must be 'forward' or 'static', got {kinematics!r}")
        self.kinematics = kinematics
        # CUDA graphs: MJX's default (Warp captures, replays for the same buffer addresses) re-captures
        # whenever XLA hands new buffers, and was the slowest on an H100 (B = 512, 640x480: 8.9k frames/s
        # static, 6.0k forward). JAX capture: 12.8k static, but mjx.forward cannot be captured by JAX;
        # staged Warp capture: 10.7k forward.
        graph = mjxw.types.GraphMode
        device = render_device()
        self._rig = geom_rig(self._mjm) if kinematics == "static" else None
        self._mx = mjx.put_model(self._mjm, impl="warp", device=device,
                                 graph_mode=graph.JAX if kinematics == "static" else graph.WARP_STAGED)
        self._dx0 = mjx.make_data(self._mjm, impl="warp", device=device)
        self._contexts: dict[int, tuple[Any, Any]] = {}

    @property
    def loads_beside_renders(self) -> bool:
        """``loads_beside_renders(self.kinematics)``."""
        return loads_beside_renders(self.kinematics)

    def _context(self, batch: int) -> tuple[Any, Any]:
        """(render context, jitted render) for ``batch`` worlds; the context must outlive its calls."""
        if batch not in self._contexts:
            intr = self.intrinsics
            try:
                rc = mjx.create_render_context(
                    mjm=self._mjm, nworld=batch, cam_res=(intr.width, intr.height), render_rgb=False,
                    render_depth=True, render_seg=True, use_textures=False, use_shadows=False,
                    enabled_geom_groups=[contract.RENDER_GROUP], cam_active=[self._cam])
            except RuntimeError as e:
                if not re.search(r"Failed to allocate \d+ bytes", str(e)):
                    raise
                raise MemoryError(out_of_memory_message(batch, intr, e)) from e
            layout = BufferLayout(depth_adr=int(rc.depth_adr.numpy()[0]), seg_adr=int(rc.seg_adr.numpy()[0]),
                                  width=intr.width, height=intr.height)
            pytree = rc.pytree()

            def render(mx: Any, dx0: Any, geom_object: jax.Array, T_wc: jax.Array, mocap_pos: jax.Array | None,
                       mocap_quat: jax.Array | None) -> DepthFrames:
                if self.kinematics == "forward":
                    dx = posed_data_forward(mx, dx0, T_wc, self._T_body_cam, self._mocap, mocap_pos, mocap_quat)
                elif mocap_pos is None:
                    dx = posed_data_static(dx0, T_wc, self._rig.rest_pos, self._rig.rest_mat, self._cam)
                else:  # the camera's own mocap set too, as mjx.forward's path does (geoms it may carry)
                    cam_pos, cam_quat = mocap_poses(T_wc, self._T_body_cam)
                    gx, gm = posed_geoms(self._rig, mocap_pos.at[:, self._mocap].set(cam_pos),
                                         mocap_quat.at[:, self._mocap].set(cam_quat))
                    dx = posed_data_static(dx0, T_wc, gx, gm, self._cam)
                depth, seg = render_buffers(mx, dx, pytree)
                return unpack_frames(depth, seg, layout, geom_object)

            self._contexts[batch] = (rc, jax.jit(render))
        return self._contexts[batch]

    def depth_fn(self, batch: int):
        """A traceable ``T_wc [batch, 4, 4] -> depth [batch, H, W]`` (m, 0 = no return) of this renderer's
        static scene: ``render``'s frames inside a caller's jit (``episode.batched.rendered``), one render
        context of ``batch`` worlds; no host-side checks on the poses."""
        _, render = self._context(batch)

        def depth(T_wc: jax.Array) -> jax.Array:
            return render(self._mx, self._dx0, self._geom_object, T_wc.astype(jnp.float32), None, None).depth

        return depth

    def render(self, T_wc: np.ndarray, mocap_pos: jax.Array | None = None,
               mocap_quat: jax.Array | None = None) -> DepthFrames:
        """T_wc: [B, 4, 4] | [4, 4]. Returns JAX [B, H, W] f32 depth and i32 object ids. With ``mocap_pos``
        [B, nmocap, 3] and ``mocap_quat`` [B, nmocap, 4], world b's mocap bodies stand there (a scene bank's
        scenes, ``world.bank``; the camera's own mocap is set from ``T_wc``)."""
        T = jax.device_put(contract.check_poses(T_wc).astype(np.float32))  # (converted on the host: no program)
        if (mocap_pos is None) != (mocap_quat is None):
            raise ValueError("warp: give mocap_pos and mocap_quat together")
        if mocap_pos is not None and (mocap_pos.shape != (T.shape[0], self._mjm.nmocap, 3)
                                      or mocap_quat.shape != (T.shape[0], self._mjm.nmocap, 4)):
            raise ValueError(f"warp: mocap_pos/quat must be [{T.shape[0]}, {self._mjm.nmocap}, 3/4], got "
                             f"{mocap_pos.shape} and {mocap_quat.shape}")
        _, render = self._context(T.shape[0])
        return render(self._mx, self._dx0, self._geom_object, T, mocap_pos, mocap_quat)
