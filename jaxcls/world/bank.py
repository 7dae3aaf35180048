"""Scenes as data: every instance an object set can put on the table in one MuJoCo model, a scene as the poses
of its bodies, so that one renderer call can draw frames of many scenes (the scale path, DESIGN.md).

Slot j of the bank is body ``object_j``, a mocap body carrying the mesh of instance ``names[j]`` (an
instance has as many slots as a scene may hold copies of it: one when scenes draw distinct instances). A
scene puts its objects' instances at their places and parks every other slot ``PARK`` m below the table,
straight under its centre: a ray reaches there only through the table (a camera of the view hemisphere does not
look straight down past the table's edge). The renderer reports slot j where it hits ``object_j``;
``SceneBank.objects`` maps slots back to the scene's object indices.

    bank = SceneBank.build(object_set, scene_config, intrinsics)
    model = bank.posed(scene)                        # the bank at rest in ``scene``: any renderer draws it
    pos, quat = bank.mocap([scene_a, scene_b])       # [S, nmocap, 3], [S, nmocap, 4]: a batch renderer's poses
"""

from __future__ import annotations

import copy
import dataclasses
import functools
from collections.abc import Sequence
from typing import TYPE_CHECKING, Literal

import numpy as np

from jaxcls import geometry
from jaxcls.world import scenes
from jaxcls.world.objects import ObjectSet
from jaxcls.world.render import make_renderer
from jaxcls.world.render.types import NO_OBJECT, Backend, DepthFrames, Renderer

if TYPE_CHECKING:
    import mujoco

PARK = 1000.0  # m below the table top where the slots a scene does not use wait
Kinematics = Literal["static", "forward"]  # how the GPU renderer poses the slots (``render.warp``)
KINEMATICS: Kinematics = "static"  # the bank's: each slot's mesh carried by its mocap pose in JAX


def launches(frames: int, batch: int) -> list[np.ndarray]:
    """The batch renderer's calls for ``frames`` frames: index arrays [batch] each, in order, the last padded
    with copies of the last frame (dropped after). Every call renders ``batch`` worlds because MuJoCo Warp's
    frames depend, in their last bits, on how many worlds a call renders (measured on an H200: a scene's frames
    rendered partly in a last call of 376 worlds differed from the same frames in calls of 1,024, and Table 1's
    oracle records with them): so a scene's frames are the same whichever scenes share its chunk, and one
    render program serves every chunk."""
    if frames < 1 or batch < 1:
        raise ValueError(f"bank: launches need frames >= 1 and batch >= 1, got {frames} and {batch}")
    index = np.minimum(np.arange(-(-frames // batch) * batch), frames - 1)
    return list(index.reshape(-1, batch))


@dataclasses.dataclass(frozen=True, eq=False)
class SceneBank:
    """One MuJoCo model for every scene of an object set and a table (see the module docstring).

    model: the bank (render contract of ``world.render.contract``; slot bodies are mocap bodies, parked);
    names: [J] the instance of each slot; table_height, table_half_size: the table every scene shares (m).
    """

    model: mujoco.MjModel
    names: tuple[str, ...]
    table_height: float
    table_half_size: float
    intrinsics: geometry.Intrinsics

    @classmethod
    def build(cls, object_set: ObjectSet, config: scenes.SceneConfig,
              intrinsics: geometry.Intrinsics | None = None) -> SceneBank:
        """The bank of the scenes ``config`` draws from ``object_set`` (its split's instances and its clutter;
        ``config.num_objects`` slots an instance where instances may repeat, else one)."""
        pool = {m.name: m for m in object_set.split(config.split) + object_set.clutter}
        copies = 1 if config.distinct_classes else config.num_objects
        names = tuple(name for name in pool for _ in range(copies))
        parked = np.eye(4)
        parked[2, 3] = config.table_height - PARK
        bodies = [(pool[name], f"mesh_{name}", parked) for name in names]
        intrinsics = intrinsics or geometry.Intrinsics.kinect_v1()
        model = scenes.compile_model(bodies, config.table_height, config.table_half_size, intrinsics, mocap=True)
        return cls(model=model, names=names, table_height=config.table_height,
                   table_half_size=config.table_half_size, intrinsics=intrinsics)

    def slots(self, scene: scenes.Scene) -> np.ndarray:
        """[K] i32 the slot of each of ``scene``'s K objects (ValueError naming what does not fit)."""
        if (scene.table_height, scene.table_half_size) != (self.table_height, self.table_half_size):
            raise ValueError(f"bank: the scene's table (height {scene.table_height}, half size "
                             f"{scene.table_half_size}) is not the bank's ({self.table_height}, "
                             f"{self.table_half_size})")
        free = {name: [j for j, n in enumerate(self.names) if n == name] for name in set(self.names)}
        out = []
        for o in scene.objects:
            if not free.get(o.name):
                raise ValueError(f"bank: instance {o.name!r} is not in the bank, or the scene holds it more "
                                 "often than the bank has slots for it")
            out.append(free[o.name].pop(0))
        return np.asarray(out, np.int32)

    def objects(self, scene: scenes.Scene) -> np.ndarray:
        """[J] i32 the scene object index standing in each slot, -1 for the parked ones."""
        out = np.full(len(self.names), -1, np.int32)
        out[self.slots(scene)] = np.arange(len(scene.objects))
        return out

    def mocap(self, scene_list: Sequence[scenes.Scene]) -> tuple[np.ndarray, np.ndarray]:
        """The mocap poses of each scene: pos [S, nmocap, 3] m and quat [S, nmocap, 4] (w, x, y, z); the
        camera's mocap keeps its rest pose (a renderer moves it)."""
        bodies = self._mocap_bodies()
        pos = np.tile(self.model.body_pos[bodies], (len(scene_list), 1, 1))
        quat = np.tile(self.model.body_quat[bodies], (len(scene_list), 1, 1))
        slot_mocap = self.model.body_mocapid[self._slot_bodies()]
        where, poses = [], []  # (scene, mocap) and the pose of every object of every scene
        for s, scene in enumerate(scene_list):
            for slot, T in zip(self.slots(scene), scene.object_poses(), strict=True):
                where.append((s, slot_mocap[slot]))
                poses.append(T)
        if poses:
            at, poses = tuple(np.array(where).T), np.stack(poses)
            pos[at] = poses[:, :3, 3]
            quat[at] = geometry.rotation_to_quat(poses[:, :3, :3])  # (one call for all: ~1 ms a call)
        return pos, quat

    def posed(self, scene: scenes.Scene) -> mujoco.MjModel:
        """A copy of the bank at rest in ``scene``'s poses: any renderer draws the scene from it (object ids
        are slots: ``objects``)."""
        model = copy.copy(self.model)
        pos, quat = self.mocap([scene])
        bodies = self._mocap_bodies()
        model.body_pos[bodies] = pos[0]
        model.body_quat[bodies] = quat[0]
        return model

    def render(self, scene_list: Sequence[scenes.Scene], T_wc: np.ndarray, backend: Backend | str = Backend.mujoco,
               batch: int = 512, kinematics: Kinematics = KINEMATICS) -> DepthFrames:
        """Frames of S scenes, each from its own V cameras ``T_wc: [S, V, 4, 4]``: depth [S, V, H, W] m (0 = no
        return) and object ids (the scene's object index, -1 table or nothing). ``warp``: every frame from the
        bank in calls of ``batch`` frames on the GPU (``launches``: the last padded; JAX arrays; ``kinematics``:
        ``warp_renderer``'s); ``mujoco`` (the CPU): each scene from ``posed`` by MuJoCo's C caster (NumPy)."""
        T_wc = np.asarray(T_wc, np.float64)
        S = len(scene_list)
        if T_wc.ndim != 4 or T_wc.shape[0] != S or T_wc.shape[2:] != (4, 4):
            raise ValueError(f"bank: T_wc must be [S, V, 4, 4] with S = {S} scenes, got {T_wc.shape}")
        V, backend = T_wc.shape[1], Backend(backend)
        objects = np.stack([self.objects(s) for s in scene_list])  # [S, J]
        if backend is Backend.mujoco:
            frames = [make_renderer(self.posed(s), self.intrinsics, backend).render(T) for s, T in
                      zip(scene_list, T_wc, strict=True)]
            depth, slot = np.stack([f.depth for f in frames]), np.stack([f.object_id for f in frames])
            ids = np.where(slot >= 0, np.take_along_axis(objects, np.maximum(slot, 0).reshape(S, -1), axis=1)
                           .reshape(slot.shape), NO_OBJECT)
            return DepthFrames(depth=depth, object_id=ids.astype(np.int32))
        if backend is not Backend.warp:
            raise ValueError(f"bank: renders with 'mujoco' (CPU) or 'warp' (GPU), not {backend!r}")
        import jax

        renderer = self.warp_renderer(kinematics)
        pos, quat = self.mocap(scene_list)  # [S, nmocap, ...]
        pos, quat = pos.astype(np.float32), quat.astype(np.float32)  # (on the host: no conversion programs)
        scene_of = np.repeat(np.arange(S), V)
        flat = T_wc.reshape(S * V, 4, 4)
        launched = [renderer.render(flat[frames], *jax.device_put((pos[scene_of[frames]], quat[scene_of[frames]])))
                    for frames in launches(S * V, batch)]
        return _scene_frames(tuple(f.depth for f in launched), tuple(f.object_id for f in launched),
                             jax.device_put(objects[scene_of].astype(np.int32)), S, V)

    def warp_renderer(self, kinematics: Kinematics = KINEMATICS) -> Renderer:
        """The bank's GPU renderer (MJX's batch renderer), built once per ``kinematics``: ``static``, each slot's
        mesh carried by its mocap pose in JAX (``render.warp.posed_geoms``), or ``forward``, ``mjx.forward``
        moving them (collision detection and constraints over the parked slots included: the reference)."""
        if kinematics not in self._warp_renderers:
            self._warp_renderers[kinematics] = make_renderer(self.model, self.intrinsics, Backend.warp,
                                                             kinematics=kinematics)
        return self._warp_renderers[kinematics]

    @functools.cached_property
    def _warp_renderers(self) -> dict[str, Renderer]:
        return {}

    def _slot_bodies(self) -> np.ndarray:
        import mujoco

        return np.array([mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, f"object_{j}")
                         for j in range(len(self.names))])

    def _mocap_bodies(self) -> np.ndarray:
        """[nmocap] the body of each mocap index."""
        order = np.full(self.model.nmocap, -1)
        for b in np.nonzero(self.model.body_mocapid >= 0)[0]:
            order[self.model.body_mocapid[b]] = b
        return order


def _scene_frames(depth: tuple, slot: tuple, table, S: int, V: int) -> DepthFrames:
    """The launches' frames (``depth``, ``slot``: [B, H, W] each, the last padded) as S scenes' [S, V, H, W], each
    pixel's slot replaced by its scene's object (``table: [S * V, J]`` the object in each slot of each frame's
    scene, -1 none), in one program: eager operations would each be a program to load when a process starts."""
    return _scene_frames_program()(depth, slot, table, S=S, V=V)


@functools.cache
def _scene_frames_program():
    """``_scene_frames``'s jitted program (JAX imported once a GPU render needs it)."""
    import jax
    import jax.numpy as jnp

    def scene_frames(depth: tuple, slot: tuple, table: jax.Array, S: int, V: int) -> DepthFrames:
        depth, slot = jnp.concatenate(depth)[:S * V], jnp.concatenate(slot)[:S * V]  # [S * V, H, W]
        ids = jnp.where(slot >= 0, jnp.take_along_axis(table, jnp.maximum(slot, 0).reshape(S * V, -1), axis=1)
                        .reshape(slot.shape), NO_OBJECT)
        H, W = depth.shape[1:]
        return DepthFrames(depth=depth.reshape(S, V, H, W), object_id=ids.reshape(S, V, H, W).astype(jnp.int32))

    return jax.jit(scene_frames, static_argnames=("S", "V"))


__all__ = ["PARK", "SceneBank"]
