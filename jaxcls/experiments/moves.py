"""Observed moves for the geometric-refinement benchmarks (``benchmarks/refine.py``, ``benchmarks/refine_batched.py``):
a move's segments, the classifier's scores and a library of one model per class, with the segments' truth."""

from __future__ import annotations

import numpy as np

from jaxcls import metrics
from jaxcls.geometry import CameraConfig
from jaxcls.perception import Spec, init_state, observe, pointnet
from jaxcls.perception.settings import PerceptionConfig
from jaxcls.world import WorldConfig, make_world

VIEWS = (0, 10, 20)  # the viewpoints fused before the move's segments are taken


def observed_move(seed: int, classifier: pointnet.Classifier):
    """One move's inputs of held-out built-in scene ``seed`` (``VIEWS`` fused at half the Kinect's resolution):
    (world, perception state, models: one per class, the scene's own instance for its classes, else the first
    held-out instance, segment truth)."""
    world = make_world(WorldConfig(camera=CameraConfig.kinect_v1(0.5), backend="mujoco"), seed=seed)
    spec = Spec.create(PerceptionConfig(), world.intrinsics, world.table_height, classifier)
    state = init_state(spec)
    for depth, T in zip(world.render(list(VIEWS)).depth, world.poses(list(VIEWS)), strict=True):
        state = observe(spec, state, depth, T)
    own = {m.class_name: m for m in world.models}
    models = [own.get(c) or next(m for m in world.object_set.test if m.class_name == c) for c in classifier.classes]
    owners = metrics.PointOwners(world.scene, world.models)
    points, mask = np.asarray(state.segments.points), np.asarray(state.segments.mask)
    truth = metrics.segment_truth(owners(points.reshape(-1, 3), mask.reshape(-1)).reshape(mask.shape), mask)
    return world, state, models, truth
