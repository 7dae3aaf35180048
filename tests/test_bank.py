"""The scene bank (``world.bank``): every instance in one MuJoCo model, a scene as its bodies' poses, renders
what the scene's own model renders (MuJoCo's C caster on both), with object ids mapped back from slots."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from jaxcls.geometry import CameraConfig, ViewpointConfig
from jaxcls.world.bank import PARK, SceneBank, launches
from jaxcls.world.render import make_renderer
from jaxcls.world.render.types import NO_OBJECT
from jaxcls.world.scenes import SceneConfig
from jaxcls.world.setup import WorldConfig, make_world

WORLD = WorldConfig(camera=CameraConfig.kinect_v1(0.25), scene=SceneConfig(num_objects=4), backend="mujoco",
                    viewpoints=ViewpointConfig(count=12))


@pytest.mark.parametrize("distinct", [True, False])
def test_the_bank_posed_in_a_scene_renders_the_scene(distinct):
    config = dataclasses.replace(WORLD, scene=dataclasses.replace(WORLD.scene, distinct_classes=distinct))
    worlds = [make_world(config, seed=s) for s in (2, 5)]
    bank = SceneBank.build(worlds[0].object_set, config.scene, worlds[0].intrinsics)
    pool = worlds[0].object_set.split("test")
    assert len(bank.names) == len(pool) * (1 if distinct else 4)
    pos, quat = bank.mocap([w.scene for w in worlds])
    assert pos.shape == (2, len(bank.names) + 1, 3) and quat.shape == (2, len(bank.names) + 1, 4)
    for world, p in zip(worlds, pos, strict=True):
        slots = bank.slots(world.scene)
        assert len(set(slots.tolist())) == len(world.scene.objects)  # a repeated instance takes another slot
        parked = np.ones(len(p), bool)
        parked[bank.model.body_mocapid[[bank.model.body(f"object_{j}").id for j in slots]]] = False
        parked[bank.model.body_mocapid[bank.model.body("camera").id]] = False
        assert np.allclose(p[parked, 2], world.table_height - PARK)
        views = np.arange(len(world.viewpoints))
        own = world.render(views)
        drawn = make_renderer(bank.posed(world.scene), world.intrinsics, "mujoco").render(world.poses(views))
        np.testing.assert_allclose(drawn.depth, own.depth, atol=1e-5)
        objects = bank.objects(world.scene)
        ids = np.where(drawn.object_id >= 0, objects[np.maximum(drawn.object_id, 0)], NO_OBJECT)
        np.testing.assert_array_equal(ids, own.object_id)
        assert set(np.unique(own.object_id)) >= set(range(len(world.scene.objects)))
    # Both scenes at once, object ids mapped back to each scene's objects (the CPU path of bank.render).
    T_wc = np.stack([w.viewpoints[:5] for w in worlds])
    frames = bank.render([w.scene for w in worlds], T_wc, "mujoco")
    for s, world in enumerate(worlds):
        own = world.render(np.arange(5))
        np.testing.assert_allclose(frames.depth[s], own.depth, atol=1e-5)
        np.testing.assert_array_equal(frames.object_id[s], own.object_id)
    with pytest.raises(ValueError, match=r"\[S, V, 4, 4\] with S = 2"):
        bank.render([w.scene for w in worlds], T_wc[:1], "mujoco")


def test_the_gpu_paths_launches_stitched_into_scenes_are_the_cpu_paths_frames():
    """``warp``'s path renders every scene's frames in launches of ``batch`` worlds (the last padded) with each
    pixel's bank slot, and stitches them in one program (``_scene_frames``) into [S, V, H, W] frames of each
    scene's objects: what the CPU path of ``bank.render`` gives, from the same slot frames."""
    from jaxcls.world.bank import _scene_frames

    worlds = [make_world(WORLD, seed=s) for s in (2, 5, 7)]
    bank = SceneBank.build(worlds[0].object_set, WORLD.scene, worlds[0].intrinsics)
    T_wc = np.stack([w.viewpoints[:3] for w in worlds])  # [3, 3, 4, 4]
    reference = bank.render([w.scene for w in worlds], T_wc, "mujoco")
    slot_frames = [make_renderer(bank.posed(w.scene), w.intrinsics, "mujoco").render(T)
                   for w, T in zip(worlds, T_wc, strict=True)]
    depth = np.concatenate([f.depth for f in slot_frames])  # [S * V, H, W], by scene then view
    slot = np.concatenate([f.object_id for f in slot_frames])
    objects = np.stack([bank.objects(w.scene) for w in worlds])[np.repeat(np.arange(3), 3)]  # [S * V, J]
    calls = launches(9, 4)  # 4 + 4 + 1 frames, the last call padded with 3 copies
    stitched = _scene_frames(tuple(depth[c] for c in calls), tuple(slot[c] for c in calls), objects, 3, 3)
    np.testing.assert_array_equal(np.asarray(stitched.depth), reference.depth)
    np.testing.assert_array_equal(np.asarray(stitched.object_id), reference.object_id)
    assert set(np.unique(reference.object_id)) > {NO_OBJECT}


def test_a_scene_that_does_not_fit_the_bank_is_refused():
    world = make_world(WORLD, seed=1)
    bank = SceneBank.build(world.object_set, WORLD.scene, world.intrinsics)
    other = make_world(dataclasses.replace(WORLD, scene=dataclasses.replace(WORLD.scene, table_height=0.1)), seed=1)
    with pytest.raises(ValueError, match="table"):
        bank.slots(other.scene)
    twice = dataclasses.replace(world.scene, objects=(world.scene.objects[0],) * 2)
    with pytest.raises(ValueError, match="more often than the bank has slots"):
        bank.slots(twice)


def test_every_batch_render_call_has_the_same_number_of_worlds():
    """``launches``: calls of exactly ``batch`` frames (MuJoCo Warp's frames depend on a call's world count), in
    order, the last padded with copies of the last frame; together every frame once."""
    for frames, batch in [(1400, 1024), (5000, 1024), (100, 1024), (2048, 1024), (1, 1)]:
        calls = launches(frames, batch)
        assert all(c.shape == (batch,) for c in calls)
        flat = np.concatenate(calls)
        np.testing.assert_array_equal(flat[:frames], np.arange(frames))
        assert (flat[frames:] == frames - 1).all() and len(flat) - frames < batch
    with pytest.raises(ValueError, match="batch >= 1"):
        launches(10, 0)


def test_the_banks_geoms_posed_in_jax_are_mujocos_kinematics():
    """The GPU path poses every slot's mesh from the scenes' mocap poses in JAX (``warp.posed_geoms``, no
    ``mjx.forward``): the same geom poses as MuJoCo's own kinematics of the bank in each scene."""
    from jaxcls.world.render import contract
    from jaxcls.world.render import warp as warp_backend

    worlds = [make_world(WORLD, seed=s) for s in (3, 4)]
    bank = SceneBank.build(worlds[0].object_set, WORLD.scene, worlds[0].intrinsics)
    pos, quat = bank.mocap([w.scene for w in worlds])
    model = contract.render_model(bank.model)
    xpos, xmat = warp_backend.posed_geoms(warp_backend.geom_rig(model), np.asarray(pos, np.float32),
                                          np.asarray(quat, np.float32))
    data = mujoco.MjData(model)
    for s in range(len(worlds)):
        data.mocap_pos[:], data.mocap_quat[:] = pos[s], quat[s]
        mujoco.mj_forward(model, data)
        placed = np.abs(data.geom_xpos[:, 2] - (WORLD.scene.table_height - PARK)) > 1.0  # parked far below
        assert placed.sum() > len(worlds[s].scene.objects)  # the scene's meshes and the table
        np.testing.assert_allclose(xpos[s], data.geom_xpos, atol=1e-4)  # float32 at 1 km below the table
        np.testing.assert_allclose(xpos[s][placed], data.geom_xpos[placed], atol=2e-6)
        np.testing.assert_allclose(xmat[s], data.geom_xmat.reshape(-1, 3, 3), atol=2e-6)
