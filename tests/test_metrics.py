"""Scoring against ground truth: segment labelling on a hand-built scene, calibration against
scikit-learn's reliability curve, and the in-scene evaluation's view paths and records."""

from __future__ import annotations

import dataclasses
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from jaxcls import metrics
from jaxcls.world import scenes
from jaxcls.world.objects import builtin_object_set


def _two_object_scene():
    objects = builtin_object_set()
    models = (objects.test[0], objects.test[4])  # two classes
    scene = scenes.arrange_scene(models, scenes.SceneConfig(), seed=0)
    by_name = {m.name: m for m in models}
    return scene, tuple(by_name[o.name] for o in scene.objects)


def _posed(scene, models, j, count, offset=0):
    T = scene.object_poses()[j]
    return (T[:3, :3] @ models[j].surface_points[offset:offset + count].T).T + T[:3, 3]


def test_segment_truth_on_a_hand_built_scene():
    scene, models = _two_object_scene()
    owners = metrics.PointOwners(scene, models)
    a, b = _posed(scene, models, 0, 90), _posed(scene, models, 1, 60)
    far = np.array([[2.0, 2.0, 0.5]] * 20)  # no object within 1 cm: table or noise
    Ps = 120
    points = np.zeros((4, Ps, 3))
    mask = np.zeros((4, Ps), bool)
    for n, block in enumerate([np.concatenate([a, b[:10]]), b[10:], np.concatenate([far, b[:5]]), np.zeros((0, 3))]):
        points[n, :len(block)], mask[n, :len(block)] = block, True
    point_owner = owners(points.reshape(-1, 3), mask.reshape(-1)).reshape(4, Ps)
    assert np.all(point_owner[~mask] == -1)
    truth = metrics.segment_truth(point_owner, mask)
    np.testing.assert_array_equal(truth.object, [0, 1, 1, -1])
    np.testing.assert_allclose(truth.purity, [90 / 100, 1.0, 5 / 25, 0.0])
    np.testing.assert_array_equal(truth.size, [100, 50, 25, 0])
    # 2 cm above an object's top is no object's; on its top it is that object's.
    T = scene.object_poses()[0]
    above, on = (T[:3, :3] @ np.array([0.0, 0.0, models[0].bounds[1, 2] + dz]) + T[:3, 3] for dz in (0.02, 0.0))
    np.testing.assert_array_equal(owners(np.stack([above, on]), np.ones(2, bool)), [-1, 0])


def test_calibration_matches_scikit_learn_reliability_curve():
    from sklearn.calibration import calibration_curve

    rng = np.random.default_rng(0)
    confidence = rng.uniform(0.05, 1.0, 2000)
    correct = rng.random(2000) < confidence ** 1.5  # over-confident
    cal = metrics.calibration(confidence, correct, bins=10)
    prob_true, prob_pred = calibration_curve(correct, confidence, n_bins=10, strategy="uniform")
    filled = cal.count > 0
    np.testing.assert_allclose(cal.accuracy[filled], prob_true, atol=1e-12)
    np.testing.assert_allclose(cal.confidence[filled], prob_pred, atol=1e-12)
    expected = sum(cal.count[b] / 2000 * abs(prob_true[i] - prob_pred[i]) for i, b in enumerate(np.flatnonzero(filled)))
    assert cal.ece == pytest.approx(expected) and cal.ece > 0.05
    perfect = metrics.calibration(np.full(1000, 0.7), np.arange(1000) < 700)
    assert perfect.ece == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match=r"must be \[K\]"):
        metrics.calibration(np.ones(3), np.ones(4, bool))


def _experiment():
    path = Path(__file__).parent.parent / "experiments" / "classify_in_scene.py"
    spec = importlib.util.spec_from_file_location("classify_in_scene", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["classify_in_scene"] = module
    spec.loader.exec_module(module)
    return module


def test_random_paths_visit_distinct_views_near_each_other():
    from jaxcls.geometry import hemisphere_viewpoints, random_view_path

    positions = hemisphere_viewpoints(np.zeros(3), 100)[:, :3, 3]
    rng = np.random.default_rng(0)
    for _ in range(5):
        path = random_view_path(rng, positions, 10, 0.5)
        assert len(set(path)) == 10
        steps = np.linalg.norm(np.diff(positions[path], axis=0), axis=1)
        assert np.all(steps <= 0.5 + 1e-9)
    assert sorted(random_view_path(rng, positions[:3], 10, 0.01)) == [0, 1, 2]  # no neighbours: nearest


def test_in_scene_evaluation_records_scored_segments():
    experiment = _experiment()
    from jaxcls.config import load_config
    from jaxcls.geometry import CameraConfig
    from jaxcls.perception import pointnet
    from jaxcls.world import WorldConfig

    shipped = load_config(experiment.InSceneConfig, "classify_in_scene")  # the shipped config loads
    assert set(shipped.worlds) == {"synthetic", "touching", "real_like"}
    assert shipped.worlds["real_like"].sensor.pose_noise
    config = experiment.InSceneConfig(scenes=1, paths=1, views=(1, 2), worlds={
        "synthetic": WorldConfig(camera=CameraConfig.kinect_v1(0.5), backend="mujoco")})
    shipped = pointnet.load_classifier()
    both = experiment.evaluate(config, {"a": shipped, "b": dataclasses.replace(shipped, temperature=1.0)},
                               show_progress=False)
    records = both["a"]
    # Every set of weights classifies the same segments (same logits here: only the temperature differs).
    assert [r["logits"] for r in both["b"]] == [r["logits"] for r in records]
    assert all(b["confidence"] >= a["confidence"] for a, b in zip(records, both["b"], strict=True))
    assert {r["views"] for r in records} == {1, 2}
    assert all(0 <= r["confidence"] <= 1 and 0 < r["purity"] <= 1 and r["size"] > 0 for r in records)
    assert len([r for r in records if r["views"] == 2]) >= 4  # most of the 5 objects are segmented
