"""Geometric refinement (Eq. 2-4): on segments of a rendered scene it keeps or corrects PointNet's class
and returns each object's pose; empty segments keep their prior; one compilation per library and config."""

from __future__ import annotations

import numpy as np
import pytest

from jaxcls import metrics
from jaxcls.geometry import CameraConfig
from jaxcls.perception import Spec, init_state, observe, pointnet, refine
from jaxcls.perception.settings import PerceptionConfig
from jaxcls.world import WorldConfig, make_world


@pytest.fixture(scope="module")
def scene():
    world = make_world(WorldConfig(camera=CameraConfig.kinect_v1(0.5), backend="mujoco"), seed=3)
    classifier = pointnet.load_classifier()
    spec = Spec.create(PerceptionConfig(), world.intrinsics, world.table_height, classifier)
    state = init_state(spec)
    views = [0, 10, 20]
    for depth, T in zip(world.render(views).depth, world.poses(views), strict=True):
        state = observe(spec, state, depth, T)
    owners = metrics.PointOwners(world.scene, world.models)
    points, mask = np.asarray(state.segments.points), np.asarray(state.segments.mask)
    truth = metrics.segment_truth(owners(points.reshape(-1, 3), mask.reshape(-1)).reshape(mask.shape), mask)
    library = refine.ModelLibrary.build(refine.library_models(world.object_set, "known"), classifier.classes)
    return world, classifier, state, truth, library


def test_refine_finds_each_objects_class_and_pose(scene):
    world, classifier, state, truth, library = scene
    config = refine.RefineConfig()
    out = refine.refine_jit(state.segments.points, state.segments.mask, state.probs, library, config,
                            world.table_height)
    poses = world.scene.object_poses()
    scored = [n for n in range(len(truth.object)) if truth.object[n] >= 0]
    assert len(scored) >= 4
    for n in scored:
        obj = truth.object[n]
        true_class = classifier.classes.index(world.scene.objects[obj].class_name)
        assert int(out.refined[n]) == true_class
        assert library.names[int(out.model[n])] == world.models[obj].name  # the instance itself wins
        angle, shift = metrics.pose_error(np.asarray(out.pose[n]), poses[obj], world.models[obj].yaw_symmetry)
        assert angle < 3.0 and shift < 0.005
    assert np.all(np.isfinite(np.asarray(out.pose))) and np.all(np.asarray(out.rho) >= 0)


def test_eq3_takes_the_best_ratio_and_empty_segments_keep_their_prior(scene):
    world, classifier, state, truth, library = scene
    config = refine.RefineConfig(top_k=3, hypotheses=4, prune_after=3, icp=refine.icp.ICPConfig(iterations=8))
    # Give the true class of segment 0 the third-highest score: GR must still pick it.
    n = int(np.flatnonzero(truth.object >= 0)[0])
    true_class = classifier.classes.index(world.scene.objects[truth.object[n]].class_name)
    probs = np.full(np.asarray(state.probs).shape, 0.01, np.float32)
    others = [c for c in range(probs.shape[1]) if c != true_class][:2]
    probs[n, others[0]], probs[n, others[1]], probs[n, true_class] = 0.5, 0.3, 0.15
    mask = np.asarray(state.segments.mask).copy()
    empty = (n + 1) % len(mask)
    mask[empty] = False
    out = refine.refine_jit(state.segments.points, mask, probs, library, config, world.table_height)
    assert int(out.prior[n]) == others[0] and int(out.refined[n]) == true_class
    assert int(np.argmax(np.asarray(out.rho[n]))) == list(np.asarray(out.candidates[n])).index(true_class)
    assert not bool(out.valid[empty]) and float(np.asarray(out.rho[empty]).max()) == 0.0
    assert int(out.refined[empty]) == int(out.prior[empty]) and int(out.model[empty]) == -1
    np.testing.assert_array_equal(np.asarray(out.pose[empty]), np.eye(4))


def test_refine_compiles_once_per_library_and_config(scene):
    world, _, state, _, library = scene
    config = refine.RefineConfig(hypotheses=2, prune_after=2, icp=refine.icp.ICPConfig(iterations=4))
    before = refine.refine_jit._cache_size()
    for shift in (0.0, 0.01, 0.02):  # new segment positions and table heights, same shapes: no retrace
        refine.refine_jit(state.segments.points + shift, state.segments.mask, state.probs, library, config,
                          world.table_height + shift)
    assert refine.refine_jit._cache_size() == before + 1


def test_library_and_config_errors_name_the_problem(scene):
    world, classifier, _, _, _ = scene
    with pytest.raises(ValueError, match="no model for classes"):
        refine.ModelLibrary.build(world.object_set.test[:4], classifier.classes)
    with pytest.raises(ValueError, match="prune_after"):
        refine.RefineConfig(prune_after=40)
    # The library kinds: the scenes' own split's instances, or the training instances only.
    assert refine.library_models(world.object_set, "known") == world.object_set.test
    assert refine.library_models(world.object_set, "category") == world.object_set.train
    assert refine.library_models(world.object_set, "known", "all") == world.object_set.train + world.object_set.test
