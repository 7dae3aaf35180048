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
    from jaxcls.geometry import hemisphere_viewpoints
    from jaxcls.planning.nbv import NBVConfig, random_walk

    T_wc = hemisphere_viewpoints(np.zeros(3), 100)
    positions = T_wc[:, :3, 3]
    rng = np.random.default_rng(0)
    for _ in range(5):
        path = random_walk(rng, T_wc, 10)  # the planner's candidate radius (nbv.radius, 0.5 m)
        assert len(set(path)) == 10
        steps = np.linalg.norm(np.diff(positions[path], axis=0), axis=1)
        assert np.all(steps <= NBVConfig().radius + 1e-6)
    assert sorted(random_walk(rng, T_wc[:3], 10, NBVConfig(radius=0.01))) == [0, 1, 2]  # no neighbours: nearest


def test_in_scene_evaluation_records_scored_segments():
    experiment = _experiment()
    from jaxcls.config import load_config
    from jaxcls.geometry import CameraConfig
    from jaxcls.perception import pointnet
    from jaxcls.perception.settings import PerceptionConfig
    from jaxcls.perception.tracking import TrackingConfig
    from jaxcls.world import WorldConfig

    shipped = load_config(experiment.InSceneConfig, "classify_in_scene")  # the shipped config loads
    assert set(shipped.worlds) == {"synthetic", "touching", "real_like"}
    assert shipped.worlds["real_like"].sensor.pose_noise
    # Frames fused at the poses given (the segments' scores are the subject, not tracking: fewer programs to
    # compile; the synthetic world's poses are exact).
    config = experiment.InSceneConfig(scenes=1, paths=1, views=(1, 2), worlds={
        "synthetic": WorldConfig(camera=CameraConfig.kinect_v1(0.5), backend="mujoco")},
        perception=PerceptionConfig(tracking=TrackingConfig(mode="reported")))
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


def test_classification_scores_match_a_hand_computed_example_and_scikit_learn():
    """true 0 0 1 1 2 2, predicted 0 1 1 (unmatched) 2 0: per class TP 1 1 1, FP 1 1 0, FN 1 1 1."""
    from sklearn.metrics import f1_score

    true, predicted = np.array([0, 0, 1, 1, 2, 2]), np.array([0, 1, 1, -1, 2, 0])
    s = metrics.classification_scores(true, predicted, 3)
    assert s.accuracy == pytest.approx((4 / 6 + 4 / 6 + 5 / 6) / 3)
    assert s.precision == pytest.approx((0.5 + 0.5 + 1.0) / 3)
    assert s.recall == pytest.approx(0.5)
    assert s.f1 == pytest.approx((0.5 + 0.5 + 2 / 3) / 3)
    assert s.plain_accuracy == pytest.approx(0.5) and s.count == 6
    assert s.f1 == pytest.approx(f1_score(true, predicted, labels=[0, 1, 2], average="macro", zero_division=0))
    with pytest.raises(ValueError, match="labels"):
        metrics.classification_scores(np.array([0, 3]), np.array([0, 0]), 3)


def test_classes_absent_from_a_sample_are_not_averaged_in():
    """Five objects of five classes out of eight, all right: every score is 1 (classes 5-7 occur nowhere);
    one wrong label brings its predicted class in, as scikit-learn's default label set does."""
    from sklearn.metrics import precision_recall_fscore_support

    true = np.arange(5)
    s = metrics.classification_scores(true, true, 8)
    assert (s.accuracy, s.precision, s.recall, s.f1) == (1.0, 1.0, 1.0, 1.0)
    predicted = np.array([0, 1, 2, 3, 6])
    s = metrics.classification_scores(true, predicted, 8)
    p, r, f, _ = precision_recall_fscore_support(true, predicted, average="macro", zero_division=0)
    assert (s.precision, s.recall, s.f1) == pytest.approx((p, r, f))
    assert s.f1 == pytest.approx(4 / 6) and s.accuracy == pytest.approx((4 * 1 + 2 * 4 / 5) / 6)


def test_scores_from_confusion_matrices_agree_with_scikit_learn_on_random_samples():
    """The vectorised scores (what the bootstraps resample) against scikit-learn on 200 random samples, with
    unmatched objects (-1) and classes absent from a sample; a stack of matrices scores as each alone."""
    from sklearn.metrics import accuracy_score, precision_recall_fscore_support

    rng = np.random.default_rng(1)
    stack, expected = [], []
    for _ in range(200):
        n = int(rng.integers(1, 12))
        true = rng.integers(0, 6, n)
        predicted = np.where(rng.random(n) < 0.3, rng.integers(-1, 6, n), true)
        s = metrics.classification_scores(true, predicted, 6)
        labels = np.union1d(true, predicted[predicted >= 0])
        p, r, f, _ = precision_recall_fscore_support(true, predicted, labels=labels, average="macro", zero_division=0)
        assert (s.precision, s.recall, s.f1) == pytest.approx((p, r, f))
        assert s.plain_accuracy == pytest.approx(accuracy_score(true, predicted)) and s.count == n
        stack.append(metrics.confusion(true, predicted, 6))
        expected.append(s.f1)
    np.testing.assert_allclose(metrics.confusion_scores(np.stack(stack))["f1"], expected)


def test_objects_are_matched_to_segments_by_hungarian_assignment():
    objects = np.array([[0.0, 0.0, 0.05], [0.2, 0.0, 0.05], [0.0, 0.2, 0.05]])
    segments = np.array([[0.19, 0.01, 0.05], [0.01, 0.0, 0.05], [0.5, 0.5, 0.0], [0.0, 0.0, 0.0]])
    valid = np.array([True, True, True, False])
    # Object 2 has no segment within 0.1 m (the one at (0.5, 0.5) is left over); the invalid one never counts.
    np.testing.assert_array_equal(metrics.match_objects(segments, valid, objects), [1, 0, -1])
    # One segment per object, at the least total distance.
    crowded = np.array([[0.05, 0.0, 0.0], [0.06, 0.0, 0.0]])
    pair = np.array([[0.0, 0, 0], [0.1, 0, 0]])
    np.testing.assert_array_equal(metrics.match_objects(crowded, np.ones(2, bool), pair), [0, 1])
    assert np.all(metrics.match_objects(segments, np.zeros(4, bool), objects) == -1)


def test_scene_bootstrap_intervals_and_the_paired_difference():
    rng = np.random.default_rng(0)

    def scenes(count, error):
        out = []
        for _ in range(count):
            true = rng.integers(0, 4, 5)
            out.append((true, np.where(rng.random(5) < error, (true + 1) % 4, true)))
        return out

    few, many = scenes(8, 0.2), scenes(60, 0.2)
    f1, low, high = metrics.scene_interval(few, 4)
    assert low <= f1 <= high
    _, low_many, high_many = metrics.scene_interval(many, 4)
    assert high_many - low_many < high - low  # more scenes, a narrower interval
    better = [(t, t.copy()) for t, _ in many]  # a perfect policy on the same scenes
    diff, low, high = metrics.paired_difference(better, many, 4)
    assert diff > 0 and low > 0  # the difference is significant
    same, low, high = metrics.paired_difference(many, many, 4)
    assert same == 0 and low == 0 and high == 0
    # The peer: scipy's bootstrap of scikit-learn's macro F1 of the pooled labels, the scenes gathered per resample.
    from scipy.stats import bootstrap
    from sklearn.metrics import f1_score

    def pooled_f1(picks):
        true = np.concatenate([few[i][0] for i in picks])
        predicted = np.concatenate([few[i][1] for i in picks])
        return f1_score(true, predicted, average="macro", zero_division=0)

    peer = bootstrap((np.arange(len(few)),), lambda picks, axis: np.apply_along_axis(pooled_f1, -1, picks),
                     vectorized=True, axis=-1, n_resamples=300, method="percentile", rng=np.random.default_rng(0))
    ours = metrics.scene_interval(few, 4, resamples=300)
    assert ours[1:] == pytest.approx((peer.confidence_interval.low, peer.confidence_interval.high), abs=1e-12)
    assert metrics.path_length(np.array([[0, 0, 0], [3, 4, 0], [3, 4, 1.0]])) == pytest.approx(6.0)
    square = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])
    assert metrics.surface_coverage(square, square[:2] + 0.001, radius=0.005) == pytest.approx(0.5)


def test_resampled_sums_equal_the_gathered_ones_and_no_scenes_score_zero():
    rng = np.random.default_rng(1)
    cms = np.stack([metrics.confusion(rng.integers(0, 4, 6), rng.integers(-1, 4, 6), 4) for _ in range(9)])
    for shape in [(9,), (5, 9), (2, 3, 9)]:
        picks = rng.integers(0, 9, shape)
        assert np.array_equal(metrics._resampled_sum(cms, picks), cms[picks].sum(axis=-3))
    # counts near float32's last exact integer (2^24), below it (float32) and above it (float64): still exact
    for top in (16_000, 17_000):
        big = rng.integers(top - 50, top + 1, (1000, 2, 2))
        picks = rng.integers(0, 1000, (3, 1000))
        assert np.array_equal(metrics._resampled_sum(big, picks), big[picks].sum(axis=-3))
    assert metrics.scene_interval([], 4) == (0.0, 0.0, 0.0)
    assert metrics.paired_difference([], [], 4) == (0.0, 0.0, 0.0)


def test_phantom_segments_count_as_false_positives_of_their_class():
    """true -1: a segment that matched no object (a phantom), a false positive of its predicted class; predicted
    -1: an object no segment matched, a false negative; (-1, -1) an empty slot, counted nowhere. The peer:
    scikit-learn with "no object" as one more label, left out of the macro average."""
    from sklearn.metrics import accuracy_score, precision_recall_fscore_support

    true = np.array([0, 1, 2, 2, -1, -1, 1, -1])
    predicted = np.array([0, 1, 1, -1, 2, 0, 1, -1])
    ours = metrics.classification_scores(true, predicted, 3)
    kept = ~((true < 0) & (predicted < 0))
    t, p = np.where(true < 0, 3, true)[kept], np.where(predicted < 0, 3, predicted)[kept]
    precision, recall, f1, _ = precision_recall_fscore_support(t, p, labels=[0, 1, 2], average="macro",
                                                               zero_division=0)
    assert (ours.precision, ours.recall, ours.f1) == pytest.approx((precision, recall, f1))
    assert ours.plain_accuracy == pytest.approx(accuracy_score(t, p)) and ours.count == 7
    without = metrics.classification_scores(true[true >= 0], predicted[true >= 0], 3)
    assert ours.recall == pytest.approx(without.recall) and ours.precision < without.precision
    assert metrics.scene_interval([(true, predicted)], 3)[0] == pytest.approx(ours.f1)
    with pytest.raises(ValueError, match="-1: no object"):
        metrics.classification_scores(np.array([-2]), np.array([0]), 3)


def test_several_intervals_in_one_bootstrap_equal_each_alone():
    """``scene_intervals`` / ``paired_differences`` (Table 1's every move and difference in one bootstrap each) give
    the bounds ``scene_interval`` / ``paired_difference`` give each set alone: the same resamples (seed)."""
    rng = np.random.default_rng(2)

    def label_set(error):
        out = []
        for _ in range(40):
            true = rng.integers(0, 4, 5)
            out.append((true, np.where(rng.random(5) < error, rng.integers(-1, 4, 5), true)))
        return out

    sets = [label_set(e) for e in (0.1, 0.3, 0.5)]
    alone = [metrics.scene_interval(x, 4, resamples=500) for x in sets]
    assert np.allclose(metrics.scene_intervals(sets, 4, resamples=500), alone, rtol=0, atol=1e-12)
    assert len({a[1:] for a in alone}) == 3  # (three different intervals)
    pairs = [(sets[0], sets[1]), (sets[2], sets[0])]
    alone = [metrics.paired_difference(a, b, 4, resamples=500) for a, b in pairs]
    assert np.allclose(metrics.paired_differences(pairs, 4, resamples=500), alone, rtol=0, atol=1e-12)
    assert metrics.scene_intervals([], 4) == [] and metrics.paired_differences([], 4) == []
    with pytest.raises(ValueError, match=r"\[39, 40\] scenes"):
        metrics.scene_intervals([sets[0], sets[1][:39]], 4)


def test_the_share_of_the_oracles_lead_is_the_ratio_of_pooled_f1s_and_undefined_where_the_oracle_ties():
    """``share_of_gap`` (Table 1: how much of the oracle's lead over the best hand-made policy the learned one
    closes): the ratio of the pooled F1 differences, an interval around it; 1 for the oracle itself and 0 for the
    base in every resample; ``SHARE_UNDEFINED`` where the oracle does not lead the base (ties or trails it)."""
    rng = np.random.default_rng(3)
    truth = [rng.integers(0, 4, 5) for _ in range(30)]

    def labels(error):
        return [(t, np.where(rng.random(5) < error, rng.integers(0, 4, 5), t)) for t in truth]

    def f1(x):
        return metrics.classification_scores(*map(np.concatenate, zip(*x, strict=True)), 4).f1

    policy, base, oracle = labels(0.3), labels(0.5), labels(0.1)
    share, low, high = metrics.share_of_gap(policy, base, oracle, 4, resamples=300)
    assert share == pytest.approx((f1(policy) - f1(base)) / (f1(oracle) - f1(base)), rel=1e-12)
    assert low < share < high and 0 < share < 1
    assert metrics.share_of_gap(oracle, base, oracle, 4, resamples=300) == pytest.approx((1, 1, 1))
    assert metrics.share_of_gap(base, base, oracle, 4, resamples=300) == (0, 0, 0)
    for weak in (base, labels(0.8)):  # an oracle that ties the base, one below it: no share, whatever the policy
        assert f1(weak) <= f1(base)
        for ours in (policy, labels(0.9)):
            assert metrics.share_of_gap(ours, base, weak, 4, resamples=300)[0] == metrics.SHARE_UNDEFINED
    with pytest.raises(ValueError, match=r"share_of_gap: .*\[29, 30\] scenes"):
        metrics.share_of_gap(policy, base[:29], oracle, 4)


def test_the_share_with_the_lead_on_all_scenes_is_its_ratio_with_a_bootstrap_stratified_by_the_oracles_scenes():
    """``share_of_gap_all_scenes``: the policy's lead over the base pooled over all N scenes, over the oracle's
    lead on its K; its interval a bootstrap that draws K of the oracle's scenes and N - K of the others (a plain
    NumPy one of those agrees); with every scene the oracle's, ``share_of_gap`` to the last bit."""
    rng = np.random.default_rng(5)
    truth = [rng.integers(0, 4, 5) for _ in range(80)]

    def labels(error, scenes=truth):
        return [(t, np.where(rng.random(5) < error, rng.integers(0, 4, 5), t)) for t in scenes]

    def f1(x):
        return metrics.classification_scores(*map(np.concatenate, zip(*x, strict=True)), 4).f1

    policy, base = labels(0.3), labels(0.6)
    inside = np.zeros(80, bool)
    inside[rng.choice(80, 30, replace=False)] = True
    oracle = labels(0.05, [t for t, i in zip(truth, inside, strict=True) if i])
    oracle_base = [b for b, i in zip(base, inside, strict=True) if i]
    share, low, high = metrics.share_of_gap_all_scenes(policy, base, oracle, oracle_base, inside, 4, resamples=4000)
    assert share == pytest.approx((f1(policy) - f1(base)) / (f1(oracle) - f1(oracle_base)), rel=1e-12)
    draws = []  # (the stratified bootstrap by hand)
    ins, outs = np.flatnonzero(inside), np.flatnonzero(~inside)
    for _ in range(4000):
        a, b = rng.integers(0, 30, 30), rng.integers(0, 50, 50)
        scenes = [*ins[a], *outs[b]]
        draws.append((f1([policy[i] for i in scenes]) - f1([base[i] for i in scenes]))
                     / (f1([oracle[i] for i in a]) - f1([oracle_base[i] for i in a])))
    assert low < share < high and (low, high) == pytest.approx(tuple(np.percentile(draws, [2.5, 97.5])),
                                                                abs=0.05 * (high - low))
    # Stratified: scenes alike within each stratum (the gain all on the oracle's scenes) give every resample the
    # same pooled counts, so no spread; a bootstrap that let the oracle's count vary would have some.
    same = [(np.arange(4), np.array(x)) for x in ([0, 1, 2, 0],) * 3 + ([0, 1, 0, 0],) * 5]
    flat = [(np.arange(4), np.array([0, 1, 0, 0]))] * 8
    lone = metrics.share_of_gap_all_scenes(same, flat, [(np.arange(4), np.arange(4))] * 3, flat[:3],
                                           np.arange(8) < 3, 4, resamples=200)
    assert 0 < lone[0] < 1 and lone == (lone[0], lone[0], lone[0])
    # Every scene the oracle's: share_of_gap itself, estimate and bounds.
    everywhere = labels(0.1)
    assert (metrics.share_of_gap_all_scenes(policy, base, everywhere, base, np.ones(80, bool), 4, resamples=300)
            == metrics.share_of_gap(policy, base, everywhere, 4, resamples=300))
    weak = labels(0.9, [t for t, i in zip(truth, inside, strict=True) if i])  # (no lead: undefined)
    assert metrics.share_of_gap_all_scenes(policy, base, weak, oracle_base, inside, 4)[0] == metrics.SHARE_UNDEFINED
    with pytest.raises(ValueError, match=r"inside marks 30 scenes, the oracle has 29"):
        metrics.share_of_gap_all_scenes(policy, base, oracle[:29], oracle_base, inside, 4)
    with pytest.raises(ValueError, match=r"the same scenes \(80, 79"):
        metrics.share_of_gap_all_scenes(policy, base[:79], oracle, oracle_base, inside, 4)


def test_scene_pooling_and_confusions_equal_the_plain_loops():
    """``protocol.per_scene`` pools each scene's runs (scenes ascending, runs in the records' order, an episode
    of fewer moves counted with its last) and ``_scene_confusions`` counts them in one bincount: both equal the
    plain per-record and per-scene loops; bad labels are refused by name."""
    from jaxcls.episode import protocol

    rng = np.random.default_rng(4)
    mixed, uniform = [], []  # targets and moves varying by record (a move at a time), or not (one conversion)
    for s in rng.permutation(7):
        for run in range(3):
            K, T = int(rng.integers(1, 5)), int(rng.choice([1, 4]))
            mixed.append({"scene": int(s), "run": run, "true": rng.integers(0, 5, K).tolist(),
                          "refined": rng.integers(-1, 5, (T, K)).tolist()})
            uniform.append({"scene": int(s), "run": run, "true": rng.integers(0, 5, 3).tolist(),
                            "refined": rng.integers(-1, 5, (4, 3)).tolist()})
    rng.shuffle(mixed)
    rng.shuffle(uniform)
    for records, move in [(records, move) for records in (mixed, uniform) for move in (1, 3, 4)]:
        pooled = protocol.per_scene(records, move)
        want = []
        for s in sorted({r["scene"] for r in records}):
            mine = [r for r in records if r["scene"] == s]
            want.append((np.concatenate([r["true"] for r in mine]),
                         np.concatenate([r["refined"][min(move, len(r["refined"])) - 1] for r in mine])))
        assert len(pooled) == len(want) == 7
        for (t, p), (wt, wp) in zip(pooled, want, strict=True):
            assert np.array_equal(t, wt) and np.array_equal(p, wp)
        assert np.array_equal(metrics._scene_confusions(pooled, 5),
                              np.stack([metrics.confusion(t, p, 5) for t, p in want]))
    assert protocol.per_scene([], 1) == []
    with pytest.raises(ValueError, match="labels must lie in"):
        metrics._scene_confusions([(np.array([0, 1]), np.array([0, 5]))], 5)
    with pytest.raises(ValueError, match="differ in length"):
        protocol.per_scene([{"scene": 0, "true": [1, 2], "refined": [[1]]}], 1)
    with pytest.raises(ValueError, match="differ in length"):  # a later move's labels short, every record alike
        protocol.per_scene([{"scene": s, "true": [1, 2], "refined": [[1, 2], [1]]} for s in (0, 1)], 1)
    with pytest.raises(ValueError, match="differ in length"):
        protocol.per_scene([{"scene": 0, "true": [1, 2], "refined": [[1, 2], [1]]},
                            {"scene": 1, "true": [1], "refined": [[1]]}], 1)


def _segments_near(rng, objects, sets, n):
    """[sets, n, 3] segment centroids, each near one of ``objects`` (a permutation, repeated), some noisy."""
    K = len(objects)
    picks = rng.permutation(np.resize(np.arange(K), max(n, K)))[:n]
    return objects[picks][None].repeat(sets, 0) + rng.normal(0, rng.choice([0.002, 0.02, 0.2]), (sets, n, 3))


def test_batched_matching_is_scipys_hungarian_assignment():
    """``match_objects_batched`` (the unique optima taken directly, the rest through SciPy) equals
    ``match_objects`` set by set: more or fewer live segments than objects, dead segments, exact ties between
    segments or between objects, pairs beyond the match distance, no segments or no objects."""
    rng = np.random.default_rng(0)
    for trial in range(300):
        B, N, K = int(rng.integers(1, 20)), int(rng.integers(0, 9)), int(rng.integers(0, 8))
        objects = rng.uniform(-0.2, 0.2, (K, 3))
        segments = _segments_near(rng, objects, B, N) if K else rng.normal(0, 0.1, (B, N, 3))
        if trial % 5 == 0 and N > 1:
            segments[:, 1] = segments[:, 0]
        if trial % 7 == 0 and K > 1:
            objects[1] = objects[0]
        valid = rng.random((B, N)) < rng.choice([0.5, 0.9, 1.0])
        want = np.stack([metrics.match_objects(segments[b], valid[b], objects) for b in range(B)])
        np.testing.assert_array_equal(metrics.match_objects_batched(segments, valid, objects), want)
    with pytest.raises(ValueError, match=r"segment_valid \[B, N\]"):
        metrics.match_objects_batched(np.zeros((2, 3, 3)), np.ones((2, 4), bool), np.zeros((1, 3)))


def test_the_oracles_candidate_scores_are_each_candidates_own():
    """``scoring.candidate_f1`` (all of a run's candidates at once: batched matching, one confusion matrix a
    candidate) gives each candidate's ``target_scores(object_labels(...)).f1`` exactly: clutter in the matching,
    dead segments, fewer segments than objects, classes of another set (-1)."""
    from jaxcls.episode import scoring

    rng = np.random.default_rng(3)
    for trial in range(60):
        K, N, C, M = int(rng.integers(1, 7)), int(rng.integers(1, 8)), int(rng.integers(1, 33)), 10
        label = rng.integers(-1 if trial % 3 == 0 else 0, M, K)
        truth = scoring.Truth(centroid=rng.uniform(-0.2, 0.2, (K, 3)), label=label, target=rng.random(K) < 0.7,
                              surface=(), names=())
        centroid = truth.centroid[rng.integers(0, K, (C, N))] + rng.normal(0, 0.03, (C, N, 3))
        valid, labels = rng.random((C, N)) < 0.8, rng.integers(0, M, (C, N))
        want = [scoring.target_scores(truth, scoring.object_labels(truth, centroid[c], valid[c], labels[c]), M).f1
                for c in range(C)]
        np.testing.assert_array_equal(scoring.candidate_f1(truth, centroid, valid, labels, M), want)


def test_a_batchs_records_match_each_move_as_the_plain_loop_does():
    """``protocol.episode_records`` (a scene's episodes matched together, every move at once, a stopped
    episode keeping its last labels) gives the labels of matching each move of each episode on its own."""
    from types import SimpleNamespace

    from jaxcls.episode import protocol, scoring

    rng = np.random.default_rng(1)
    E, T, N, K = 60, 6, 6, 5
    truths = [SimpleNamespace(centroid=rng.uniform(-0.2, 0.2, (K, 3)), label=rng.integers(0, 8, K),
                              target=np.array([0, 2, 3])) for _ in range(6)]
    scene = np.repeat(np.arange(6), 10)
    centroid = np.stack([_segments_near(rng, truths[s].centroid, T, N) for s in scene])  # [E, T, N, 3]
    done = np.cumsum(rng.random((E, T)) < 0.15, axis=1) > 0
    refinement = SimpleNamespace(prior=rng.integers(0, 8, (E, T, N)), refined=rng.integers(0, 8, (E, T, N)),
                                 valid=rng.random((E, T, N)) < 0.8)
    traces = SimpleNamespace(refinement=refinement, centroid=centroid, done=done, view=rng.integers(0, 30, (E, T)),
                             tracking=np.zeros((E, T), np.int32), hand_eye=np.tile(np.eye(4), (E, T, 1, 1)))
    records = protocol.episode_records(traces, [truths[s] for s in scene], [{"run": e} for e in range(E)])
    for e, record in enumerate(records):
        truth, labels = truths[scene[e]], []
        for t in range(T):
            labels.append(labels[-1] if done[e, t] and labels else scoring.object_labels(
                truth, centroid[e, t], refinement.valid[e, t],
                np.stack([refinement.prior[e, t], refinement.refined[e, t]]))[:, truth.target])
        labels = np.stack(labels)
        assert record["prior"] == labels[:, 0].tolist() and record["refined"] == labels[:, 1].tolist()
        assert record["path"] == traces.view[e][~done[e]].tolist()


def test_the_assignment_in_jax_is_scipys():
    """``math.linear_sum_assignment`` (JAX, jit and vmap) against ``scipy.optimize.linear_sum_assignment`` on random
    rectangular costs (ties have measure zero): the same column for every row."""
    import jax
    import jax.numpy as jnp
    from scipy.optimize import linear_sum_assignment as scipy_assignment

    from jaxcls.math import linear_sum_assignment

    rng = np.random.default_rng(0)
    for n, m in [(1, 1), (1, 5), (3, 3), (4, 9), (7, 7), (6, 12)]:
        costs = rng.random((20, n, m)).astype(np.float32) * rng.choice([0.01, 1.0, 100.0])
        got = np.asarray(jax.jit(jax.vmap(linear_sum_assignment))(jnp.asarray(costs)))
        for cost, cols in zip(costs, got, strict=True):
            np.testing.assert_array_equal(cols, scipy_assignment(cost)[1])
    with pytest.raises(ValueError, match="3 rows and 2 columns"):
        linear_sum_assignment(jnp.zeros((3, 2)))


def test_the_target_f1_in_jax_is_the_hosts():
    """``scoring.target_f1`` (JAX: a reward inside a jitted rollout) gives ``scoring.candidate_f1``'s number (the
    oracle's, SciPy's assignment) for sets of segments with more, as many and fewer live segments than objects,
    clutter and padded objects."""
    import jax
    import jax.numpy as jnp

    from jaxcls.episode import scoring

    rng = np.random.default_rng(1)
    f1 = jax.jit(jax.vmap(lambda t, c, v, lab: scoring.target_f1(t, c, v, lab, 5), in_axes=(None, 0, 0, 0)))
    fewer = 0
    for _ in range(60):
        K = int(rng.integers(1, 9))
        centre = rng.uniform(-0.5, 0.5, (K, 3))
        truth = scoring.Truth(centroid=centre, label=rng.integers(-1, 5, K), target=rng.random(K) < 0.7,
                              surface=(), names=())
        segments = centre[rng.integers(0, K, (6, 10))] + rng.normal(0, 0.06, (6, 10, 3))
        valid = rng.random((6, 10)) < rng.uniform(0.2, 0.9)
        labels = rng.integers(0, 5, (6, 10))
        fewer += int((valid.sum(axis=1) < K).sum())
        got = f1(scoring.TruthArrays.of(truth, 8), jnp.asarray(segments, jnp.float32), jnp.asarray(valid),
                 jnp.asarray(labels))
        np.testing.assert_allclose(np.asarray(got), scoring.candidate_f1(truth, segments, valid, labels, 5), atol=1e-6)
    assert fewer > 20  # (the case where a dead segment's cost decides)
    with pytest.raises(ValueError, match="9 objects"):
        scoring.TruthArrays.of(scoring.Truth(np.zeros((9, 3)), np.zeros(9, int), np.ones(9, bool), (), ()), 8)
