"""``perception.observe``, the one owner of a move: it equals its stages run one by one, it vmaps over
episodes, the reference segmenter runs through it, and the table height flows from the world to it."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcls import perception
from jaxcls.geometry import CameraConfig
from jaxcls.perception import foreground, pointnet, segment, tsdf
from jaxcls.perception.settings import PerceptionConfig, ShapeConfig, Spec
from jaxcls.perception.tracking import TrackingConfig
from jaxcls.world import scenes
from jaxcls.world.setup import WorldConfig, make_world

CAMERA = CameraConfig.kinect_v1(0.5)
VIEWS = [20, 50, 80]
SHAPES = ShapeConfig(surface_points=8192, points_per_segment=512)
UNTRACKED = TrackingConfig(mode="reported")  # frames fused at the poses given, as the hand-wired chain does


@pytest.fixture(scope="module")
def classifier():
    return pointnet.load_classifier()


def _frames(table_height: float = 0.0, seed: int = 0):
    world = make_world(WorldConfig(scene=scenes.SceneConfig(table_height=table_height), camera=CAMERA,
                                   backend="mujoco"), seed)
    return world, np.asarray(world.render(VIEWS).depth), world.poses(VIEWS)


def test_observe_is_its_stages_composed(classifier):
    world, depth, poses = _frames()
    spec = Spec.create(PerceptionConfig(shapes=SHAPES, tracking=UNTRACKED), world.intrinsics, world.table_height,
                       classifier)
    state = perception.init_state(spec)
    volume = perception.empty_volume(spec)
    for d, T in zip(depth, poses, strict=True):
        state = perception.observe(spec, state, d, T)
        T32 = jnp.asarray(T, jnp.float32)
        volume = tsdf.integrate(volume, foreground.foreground_depth(spec, jnp.asarray(d), T32), world.intrinsics, T32)
    surface = tsdf.extract_surface(volume, SHAPES.surface_points)
    segments = segment.segment_jax(spec, surface.points, surface.normals, surface.mask)
    probs = pointnet.classify(classifier, segments.points, segments.mask)
    assert int(state.frames) == len(VIEWS)
    np.testing.assert_allclose(np.asarray(state.volume.tsdf), np.asarray(volume.tsdf), atol=1e-6)
    np.testing.assert_array_equal(np.asarray(state.segments.labels), np.asarray(segments.labels))
    np.testing.assert_allclose(np.asarray(state.segments.points), np.asarray(segments.points), atol=1e-6)
    np.testing.assert_allclose(np.asarray(state.probs), np.asarray(probs), atol=1e-5)
    assert state.probs.shape == (SHAPES.num_segments, len(classifier.classes))


def test_the_batch_memory_layout_gives_the_same_observation(classifier):
    """``volume.slabs`` (the fusion in slabs along x) and ``shapes.segments_per_pass`` (PointNet in passes) cut a
    GPU batch's memory; they give what one pass over the volume and the segments together give."""
    import dataclasses

    from jaxcls.geometry import Intrinsics, look_at

    small = Intrinsics.kinect_v1(0.25)
    rng = np.random.default_rng(0)
    depth = jnp.asarray(rng.uniform(0.9, 1.1, (small.height, small.width)), jnp.float32)
    T = jnp.asarray(look_at(np.array([0.1, 0.0, 1.0]), np.zeros(3)), jnp.float32)
    volume = tsdf.create_volume(np.zeros(3), size=0.3, resolution=24)
    one, slabs = (tsdf.integrate(volume, depth, small, T, slabs=n) for n in (1, 8))
    np.testing.assert_array_equal(np.asarray(slabs.weight), np.asarray(one.weight))
    # 1e-5: XLA may contract a slab's multiply-adds differently (~1 float32 ulp of z / truncation).
    np.testing.assert_allclose(np.asarray(slabs.tsdf), np.asarray(one.tsdf), atol=1e-5)
    assert np.asarray(one.weight).sum() > 0

    points = jnp.asarray(rng.normal(size=(5, 64, 3)) * 0.05, jnp.float32)
    segments = segment.Segments(points=points, normals=points, mask=jnp.ones((5, 64), bool),
                                labels=jnp.zeros(8, jnp.int32))
    base = PerceptionConfig(shapes=dataclasses.replace(SHAPES, points_per_segment=64))
    together = perception.observation.classify_segments(Spec.create(base, classifier=classifier), segments)
    for per_pass in (1, 2):
        config = dataclasses.replace(base, shapes=dataclasses.replace(base.shapes, segments_per_pass=per_pass))
        passes = perception.observation.classify_segments(Spec.create(config, classifier=classifier), segments)
        for a, b in zip(passes, together, strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-5)
    with pytest.raises(ValueError, match=r"volume\.slabs \(3\) must divide volume\.resolution \(128\)"):
        dataclasses.replace(base.volume, slabs=3)


def test_perceive_vmaps_over_episodes_and_jits():
    episodes = [_frames(seed=s) for s in (0, 1)]
    spec = Spec.create(PerceptionConfig(shapes=SHAPES), episodes[0][0].intrinsics)
    batched = jax.jit(jax.vmap(perception.perceive, in_axes=(None, 0, 0, 0)))
    state = jax.tree.map(lambda x: jnp.stack([x, x]), perception.init_state(spec))
    for v in range(len(VIEWS)):
        depth = jnp.stack([jnp.asarray(e[1][v]) for e in episodes])
        poses = jnp.stack([jnp.asarray(e[2][v], jnp.float32) for e in episodes])
        state = batched(spec, state, depth, poses)
    for i, (_, depth, poses) in enumerate(episodes):
        alone = perception.init_state(spec)
        for d, T in zip(depth, poses, strict=True):
            alone = perception.observe(spec, alone, d, T)
        np.testing.assert_array_equal(np.asarray(state.segments.labels[i]), np.asarray(alone.segments.labels))
        # (batched and alone are different XLA:CPU programs, vectorised otherwise: the tracked poses and fused values
        # may round otherwise, a few micrometres on a point on some CPUs; 2.9e-6 m seen on a Xeon @ 2.5 GHz)
        np.testing.assert_allclose(np.asarray(state.segments.points[i]), np.asarray(alone.segments.points),
                                   atol=1e-5)
    assert state.probs.shape == (2, SHAPES.num_segments, 0)  # no classifier: no scores


def test_reference_segmenter_through_observe_agrees_with_the_twin():
    from sklearn.metrics import adjusted_rand_score

    world, depth, poses = _frames()
    twin = Spec.create(PerceptionConfig(shapes=SHAPES), world.intrinsics)
    ref = Spec.create(PerceptionConfig(shapes=SHAPES, segmenter="reference"), world.intrinsics)
    a, b = perception.init_state(twin), perception.init_state(ref)
    for d, T in zip(depth, poses, strict=True):
        a, b = perception.observe(twin, a, d, T), perception.observe(ref, b, d, T)
    la, lb = np.asarray(a.segments.labels), np.asarray(b.segments.labels)
    either = (la >= 0) | (lb >= 0)
    assert either.sum() > 1000 and adjusted_rand_score(la[either], lb[either]) >= 0.95
    # The reference path traces into a jitted move too (scikit-learn through a host callback): same segments.
    c = perception.init_state(ref)
    for d, T in zip(depth, poses, strict=True):
        c = jax.jit(perception.perceive)(ref, c, jnp.asarray(d), jnp.asarray(T, jnp.float32))
    np.testing.assert_array_equal(np.asarray(c.segments.labels), lb)


def test_the_table_height_flows_from_the_world_to_perception():
    """The same scene on a table 0.3 m higher: the volume, the table band and the segments move up with it
    (the scene's height is the one owner; perception reads it through the spec)."""
    lift = 0.3
    low, high = _frames(0.0), _frames(lift)
    np.testing.assert_allclose(high[2][:, :3, 3] - low[2][:, :3, 3], np.tile([0, 0, lift], (len(VIEWS), 1)),
                               atol=1e-9)
    segments = []
    for world, depth, poses in (low, high):
        spec = Spec.create(PerceptionConfig(shapes=SHAPES, tracking=UNTRACKED), world.intrinsics, world.table_height)
        assert spec.roi_center[2] == pytest.approx(0.25 + world.table_height)
        state = perception.init_state(spec)
        for d, T in zip(depth, poses, strict=True):
            state = perception.observe(spec, state, d, T)
        segments.append(state.segments)
    a, b = segments
    assert int(a.mask.sum()) > 1000
    np.testing.assert_array_equal(np.asarray(a.mask), np.asarray(b.mask))
    shift = np.asarray(b.points)[np.asarray(b.mask)] - np.asarray(a.points)[np.asarray(a.mask)]
    np.testing.assert_allclose(shift, np.tile([0, 0, lift], (len(shift), 1)), atol=2e-5)


def test_observe_refuses_bad_frames_naming_the_problem():
    spec = Spec.create()
    state = perception.init_state(spec)
    with pytest.raises(ValueError, match=r"depth has shape \(10, 10\)"):
        perception.observe(spec, state, np.zeros((10, 10), np.float32), np.eye(4))
    bad_pose = np.eye(4)
    bad_pose[0, 0] = 2.0
    with pytest.raises(ValueError, match="not rigid"):
        perception.observe(spec, state, np.zeros((480, 640), np.float32), bad_pose)
