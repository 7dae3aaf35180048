"""Scoring perception against the world's ground truth: which object each surface point and each segment
belongs to, classification accuracy, and calibration (expected calibration error, reliability bins).

Host-side NumPy/SciPy (evaluation, not the jitted loop). Ground truth comes from the scene: the posed
surface samples of its object models; a point farther than ``radius`` from every object is table or noise.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from jaxcls.world.objects import ObjectModel
from jaxcls.world.scenes import Scene

OWNER_RADIUS = 0.01  # m: a surface point farther than this from every posed object surface is no object's


class PointOwners:
    """Nearest posed object of world points: a KD-tree over the scene's posed surface samples.

    owners(points [P, 3], mask [P]) -> [P] i64 index into ``scene.objects``, -1 = masked, table or noise.
    """

    def __init__(self, scene: Scene, models: Sequence[ObjectModel], radius: float = OWNER_RADIUS):
        samples = scene.posed_surfaces(models)
        self.owner = np.concatenate([np.full(len(s), i) for i, s in enumerate(samples)])
        self.tree = cKDTree(np.concatenate(samples))
        self.radius = radius

    def __call__(self, points: np.ndarray, mask: np.ndarray) -> np.ndarray:
        points, mask = np.asarray(points, np.float64), np.asarray(mask, bool)
        d, idx = self.tree.query(points)
        return np.where(mask & (d < self.radius), self.owner[idx], -1)


@dataclasses.dataclass(frozen=True)
class SegmentTruth:
    """Each segment's ground truth. object: [N] i64 majority object (-1: no point belongs to an object);
    purity: [N] f64 share of the segment's points that belong to it (0 for an empty segment); size: [N] i64
    points in the segment."""

    object: np.ndarray
    purity: np.ndarray
    size: np.ndarray


def segment_truth(owners: np.ndarray, mask: np.ndarray) -> SegmentTruth:
    """Majority object and purity of segments from their points' owners.

    owners: [N, Ps] i64 object of each segment point (-1: none); mask: [N, Ps] bool real points.
    Ties go to the lower object index. Purity counts all real points, unowned ones included.
    """
    owners, mask = np.asarray(owners), np.asarray(mask, bool)
    num_objects = int(owners.max(initial=-1)) + 1
    counts = np.stack([((owners == j) & mask).sum(axis=1) for j in range(num_objects)], axis=1) \
        if num_objects else np.zeros((len(owners), 0), int)
    size = mask.sum(axis=1)
    best = counts.argmax(axis=1) if num_objects else np.zeros(len(owners), int)
    top = counts[np.arange(len(owners)), best] if num_objects else np.zeros(len(owners), int)
    return SegmentTruth(object=np.where(top > 0, best, -1), purity=np.where(size > 0, top / np.maximum(size, 1), 0.0),
                        size=size)


@dataclasses.dataclass(frozen=True)
class Calibration:
    """Reliability of top-1 confidences in ``bins`` equal-width bins over [0, 1].

    ece: expected calibration error, sum over bins of (bin share) x |accuracy - mean confidence|;
    confidence, accuracy: [B] per-bin means (NaN for an empty bin); count: [B] i64 predictions per bin.
    """

    ece: float
    confidence: np.ndarray
    accuracy: np.ndarray
    count: np.ndarray


def calibration(confidence: np.ndarray, correct: np.ndarray, bins: int = 10) -> Calibration:
    """``Calibration`` of predictions with top-1 probability ``confidence: [K]`` and ``correct: [K]`` bool.

    Bin b holds confidences in (b / bins, (b + 1) / bins]; a confidence of exactly 0 falls in bin 0.
    """
    confidence, correct = np.asarray(confidence, np.float64), np.asarray(correct, bool)
    if confidence.shape != correct.shape or confidence.ndim != 1:
        raise ValueError(f"calibration: confidence and correct must be [K] alike, got {confidence.shape} and "
                         f"{correct.shape}")
    which = np.clip(np.ceil(confidence * bins).astype(int) - 1, 0, bins - 1)
    count = np.bincount(which, minlength=bins)
    with np.errstate(invalid="ignore"):
        mean_conf = np.bincount(which, confidence, minlength=bins) / count
        mean_acc = np.bincount(which, correct.astype(float), minlength=bins) / count
    total = max(len(confidence), 1)
    ece = float(np.nansum(count / total * np.abs(mean_acc - mean_conf)))
    return Calibration(ece=ece, confidence=mean_conf, accuracy=mean_acc, count=count)


def pose_error(estimate: np.ndarray, truth: np.ndarray, symmetry: int = 1) -> tuple[float, float]:
    """(rotation error in degrees, translation error in metres) of a model-to-world ``estimate`` [4, 4]
    against ``truth`` [4, 4], modulo the model's rotational symmetry about its z axis (``ObjectModel.
    yaw_symmetry``: 0 = continuous, only the tilt of the axis counts; k >= 1 = the nearest of the k turns).
    The symmetry axis is the model frame's z axis through its origin, so translations compare directly."""
    R_est, R_true = np.asarray(estimate, np.float64)[:3, :3], np.asarray(truth, np.float64)[:3, :3]
    translation = float(np.linalg.norm(np.asarray(estimate, np.float64)[:3, 3] - np.asarray(truth, np.float64)[:3, 3]))
    if symmetry == 0:
        cos = np.clip(R_est[:, 2] @ R_true[:, 2], -1.0, 1.0)
        return float(np.degrees(np.arccos(cos))), translation
    angles = []
    for j in range(max(symmetry, 1)):
        c, s = np.cos(2 * np.pi * j / symmetry), np.sin(2 * np.pi * j / symmetry)
        turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        relative = (R_true @ turn).T @ R_est
        angles.append(np.degrees(np.arccos(np.clip((np.trace(relative) - 1) / 2, -1.0, 1.0))))
    return float(min(angles)), translation


# --- Episode scores (the paper's Sec. 4 protocol) --------------------------------------------------------

MATCH_DISTANCE = 0.1  # m: a segment farther than this from an object's centroid is no match for it


def match_objects(segment_centroids: np.ndarray, segment_valid: np.ndarray, object_centroids: np.ndarray,
                  max_distance: float = MATCH_DISTANCE) -> np.ndarray:
    """[K] i64: the segment matched to each object (-1: none), by Hungarian assignment on centroid distance
    (``scipy.optimize.linear_sum_assignment``). Every object takes part (clutter too, so that a clutter
    segment never stands in for a target); pairs farther apart than ``max_distance`` are no match.

    segment_centroids: [N, 3] m; segment_valid: [N] bool; object_centroids: [K, 3] m."""
    return _hungarian(*_match_inputs(segment_centroids, segment_valid, object_centroids, sets=False), max_distance)


def _match_inputs(segment_centroids: np.ndarray, segment_valid: np.ndarray, object_centroids: np.ndarray,
                  sets: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(segments f64, valid bool, objects f64) of a matcher, or ValueError naming the shapes: [N, 3], [N] (or
    with ``sets`` [B, N, 3], [B, N]) and [K, 3]."""
    seg = np.asarray(segment_centroids, np.float64)
    obj = np.asarray(object_centroids, np.float64)
    valid = np.asarray(segment_valid, bool)
    if (seg.ndim != 2 + sets or seg.shape[-1] != 3 or valid.shape != seg.shape[:-1] or obj.ndim != 2
            or obj.shape[1] != 3):
        lead = "B, " if sets else ""
        raise ValueError(f"match_objects{'_batched' if sets else ''}: need segment_centroids [{lead}N, 3], "
                         f"segment_valid [{lead}N], object_centroids [K, 3]; got {seg.shape}, {valid.shape}, "
                         f"{obj.shape}")
    return seg, valid, obj


def _hungarian(seg: np.ndarray, valid: np.ndarray, obj: np.ndarray, max_distance: float) -> np.ndarray:
    """``match_objects`` on checked inputs: SciPy's assignment over the live segments."""
    from scipy.optimize import linear_sum_assignment

    out = np.full(len(obj), -1, np.int64)
    live = np.flatnonzero(valid)
    if not len(live) or not len(obj):
        return out
    cost = np.linalg.norm(obj[:, None, :] - seg[None, live, :], axis=-1)
    rows, cols = linear_sum_assignment(cost)
    keep = cost[rows, cols] <= max_distance
    out[rows[keep]] = live[cols[keep]]
    return out


def match_objects_batched(segment_centroids: np.ndarray, segment_valid: np.ndarray, object_centroids: np.ndarray,
                          max_distance: float = MATCH_DISTANCE) -> np.ndarray:
    """``match_objects`` of B sets of segments against one scene's objects at once: [B, K] i64.

    With at least as many live segments as objects, where each object's nearest live segment is strictly nearer
    than its others and no two objects share one, that pairing is the assignment's unique optimum (its cost, the
    sum of the row minima, bounds every assignment's, and any other pays strictly more), so it is SciPy's answer
    too; with fewer live segments, the same holds for each segment's nearest object. Those sets are matched here
    all at once; the others go through ``match_objects`` (SciPy's Hungarian).

    segment_centroids: [B, N, 3] m; segment_valid: [B, N] bool; object_centroids: [K, 3] m."""
    seg, valid, obj = _match_inputs(segment_centroids, segment_valid, object_centroids, sets=True)
    (B, N), K = valid.shape, len(obj)
    out = np.full((B, K), -1, np.int64)
    if not B or not K or not N:
        return out
    # The same float64 distances as match_objects' (the same expression, element by element).
    cost = np.linalg.norm(obj[None, :, None, :] - seg[:, None, :, :], axis=-1)  # [B, K, N]
    live = valid.sum(axis=-1)
    rows = live >= K  # every object gets a segment: each object's nearest segment
    by_row = np.where(valid[:, None, :], cost, np.inf)
    seg_of, row_ok = _strict_nearest(by_row)  # [B, K]
    fast_rows = rows & row_ok.all(axis=-1) & _distinct(seg_of)
    # every live segment gets an object: each segment's nearest object (a dead segment's own negative tag)
    obj_of, col_ok = _strict_nearest(np.swapaxes(cost, 1, 2))  # [B, N]
    fast_cols = ~rows & np.all(col_ok | ~valid, axis=-1) & _distinct(np.where(valid, obj_of, -1 - np.arange(N)))
    near = np.take_along_axis(by_row, seg_of[..., None], axis=-1)[..., 0] <= max_distance
    out[fast_rows] = np.where(near[fast_rows], seg_of[fast_rows], -1)
    for b in np.flatnonzero(fast_cols):
        n = np.flatnonzero(valid[b] & (cost[b, obj_of[b], np.arange(N)] <= max_distance))
        out[b, obj_of[b, n]] = n
    for b in np.flatnonzero(~fast_rows & ~fast_cols):
        out[b] = _hungarian(seg[b], valid[b], obj, max_distance)
    return out


def _strict_nearest(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(argmin over the last axis, whether that minimum is finite and strictly below the rest) of ``cost``."""
    nearest = np.argmin(cost, axis=-1)
    first = np.take_along_axis(cost, nearest[..., None], axis=-1)[..., 0]
    second = np.partition(cost, 1, axis=-1)[..., 1] if cost.shape[-1] > 1 else np.full(first.shape, np.inf)
    return nearest, np.isfinite(first) & (first < second)


def _distinct(values: np.ndarray) -> np.ndarray:
    """[B] whether the entries of each row of ``values`` [B, n] differ."""
    ordered = np.sort(values, axis=-1)
    return np.all(ordered[:, 1:] != ordered[:, :-1], axis=-1)


@dataclasses.dataclass(frozen=True)
class Scores:
    """Classification of target objects, macro-averaged over the classes as the paper does.

    accuracy: one-vs-all accuracy, (TP + TN) / n per class, averaged (the paper's "Accuracy"; it runs far
    above ``plain_accuracy``); precision, recall, f1: scikit-learn's macro averages (zero_division=0);
    plain_accuracy: the share of objects labelled right; count: objects scored.
    """

    accuracy: float
    precision: float
    recall: float
    f1: float
    plain_accuracy: float
    count: int


def confusion(true: np.ndarray, predicted: np.ndarray, num_classes: int) -> np.ndarray:
    """[M + 1, M + 1] i64 counts of (true, predicted) labels; row/column M holds "no object" / "no class":
    predicted -1, an object no segment matched (a false negative of its class); true -1, a segment that matched
    no object (a phantom: a false positive of its predicted class). A pair of two -1s (an empty slot) is not
    counted. true: [n] in [-1, M); predicted: [n] in [-1, M)."""
    true, predicted = _checked_labels(true, predicted, num_classes)
    cm = np.zeros((num_classes + 1, num_classes + 1), np.int64)
    np.add.at(cm, (np.where(true < 0, num_classes, true), np.where(predicted < 0, num_classes, predicted)), 1)
    cm[num_classes, num_classes] = 0
    return cm


def _checked_labels(true: np.ndarray, predicted: np.ndarray, num_classes: int) -> tuple[np.ndarray, np.ndarray]:
    """(true, predicted) as i64 [n] each, or ValueError naming what is wrong (``confusion``'s ranges)."""
    true, predicted = np.asarray(true, np.int64), np.asarray(predicted, np.int64)
    if true.shape != predicted.shape or true.ndim != 1:
        raise ValueError(f"classification_scores: need true [n] and predicted [n], got {true.shape}, {predicted.shape}")
    if len(true) and (true.min() < -1 or true.max() >= num_classes or predicted.max() >= num_classes
                      or predicted.min() < -1):
        raise ValueError(f"classification_scores: labels must lie in [0, {num_classes}) (-1: no object / no class)")
    return true, predicted


def confusion_scores(cm: np.ndarray) -> dict[str, np.ndarray]:
    """``Scores``' statistics of confusion matrices ``cm: [..., M + 1, M + 1]`` (``confusion``), vectorised over
    the leading axes (a bootstrap's resamples): each a [...] array. Macro averages run over the classes that
    occur in the truth or the predictions of each matrix (scikit-learn's default label set, zero_division=0),
    so that a class absent from both does not drag a small sample down."""
    cm = np.asarray(cm, np.float64)
    cls = cm[..., :-1, :-1]
    tp = np.diagonal(cls, axis1=-2, axis2=-1)
    true_count = cm[..., :-1, :].sum(axis=-1)  # objects of each class (unmatched ones too)
    pred_count = cm[..., :, :-1].sum(axis=-2)  # labelled with each class: objects, and phantoms (row M)
    n = cm.sum(axis=(-2, -1))
    occurs = (true_count > 0) | (pred_count > 0)
    classes = np.maximum(occurs.sum(axis=-1), 1)

    def ratio(a, b):
        return np.divide(a, b, out=np.zeros_like(a), where=b > 0)

    precision, recall = ratio(tp, pred_count), ratio(tp, true_count)
    f1 = ratio(2 * precision * recall, precision + recall)
    fp, fn = pred_count - tp, true_count - tp
    one_vs_all = ratio(n[..., None] - fp - fn, np.broadcast_to(n[..., None], fp.shape))

    def macro(x):
        return np.where(occurs, x, 0.0).sum(axis=-1) / classes

    return {"accuracy": macro(one_vs_all), "precision": macro(precision), "recall": macro(recall), "f1": macro(f1),
            "plain_accuracy": ratio(tp.sum(axis=-1), n), "count": n}


def classification_scores(true: np.ndarray, predicted: np.ndarray, num_classes: int) -> Scores:
    """Scores of labels ``predicted: [n]`` (class indices; -1 = the object was not matched by any segment,
    which counts as wrong) against ``true: [n]`` (-1: a segment that matched no object, a phantom, which counts
    as a false positive of its predicted class), macro-averaged over the classes (of 0..num_classes-1)
    that occur in ``true`` or ``predicted``: what scikit-learn's ``precision_recall_fscore_support(average=
    "macro", zero_division=0)`` gives (checked in the tests), from the confusion matrix so that a bootstrap
    can score thousands of resamples at once (``confusion_scores``)."""
    cm = confusion(true, predicted, num_classes)
    if not cm.sum():
        return Scores(0.0, 0.0, 0.0, 0.0, 0.0, 0)
    stats = confusion_scores(cm)
    return Scores(**{k: float(v) for k, v in stats.items() if k != "count"}, count=int(stats["count"]))


def _scene_confusions(per_scene: Sequence[tuple[np.ndarray, np.ndarray]], num_classes: int) -> np.ndarray:
    """[S, M + 1, M + 1]: each scene's confusion matrix (``confusion``; resampled whole by the bootstraps), all
    counted in one ``bincount`` over (scene, true, predicted)."""
    S, M = len(per_scene), num_classes + 1
    if not S:
        return np.zeros((0, M, M), np.int64)
    for t, p in per_scene:
        if np.shape(t) != np.shape(p) or np.ndim(t) != 1:
            raise ValueError(f"classification_scores: need true [n] and predicted [n] per scene, got {np.shape(t)}, "
                             f"{np.shape(p)}")
    true, predicted = _checked_labels(np.concatenate([t for t, _ in per_scene]),
                                      np.concatenate([p for _, p in per_scene]), num_classes)
    scene = np.repeat(np.arange(S), [len(t) for t, _ in per_scene])
    cell = (scene * M + np.where(true < 0, num_classes, true)) * M + np.where(predicted < 0, num_classes, predicted)
    cms = np.bincount(cell, minlength=S * M * M).reshape(S, M, M)
    cms[:, num_classes, num_classes] = 0  # (empty slots: no object, no class)
    return cms


def _resampled_sum(cms: np.ndarray, picks: np.ndarray) -> np.ndarray:
    """``cms[picks].sum(axis=-3)`` without the [..., S, M + 1, M + 1] gather: each resample's scene counts
    ([..., S], a bincount) times the scenes' matrices ``cms: [S, M + 1, M + 1]``, one matrix product. Every
    product and partial sum is an integer no larger than ``picks.shape[-1] * cms.max()``: in float32 (about twice
    as fast) where that is below 2^24, else in float64 (below 2^53): exact either way, so the sums equal the
    gathered ones whatever order the product adds in."""
    picks = np.asarray(picks)
    n, lead = len(cms), picks.shape[:-1]
    if not n or not picks.shape[-1]:  # no scenes: every sum is empty
        return np.zeros((*lead, *cms.shape[1:]))
    rows = np.arange(int(np.prod(lead)))[:, None] * n
    counts = np.bincount((rows + picks.reshape(-1, picks.shape[-1])).ravel(), minlength=len(rows) * n)
    exact = np.float32 if picks.shape[-1] * max(int(cms.max()), 1) < 2**24 else np.float64
    sums = counts.reshape(-1, n).astype(exact) @ cms.reshape(n, -1).astype(exact)
    return sums.astype(np.float64).reshape(*lead, *cms.shape[1:])


def _interval(statistic_of, n: int | tuple[int, ...], confidence: float, resamples: int, seed: int
              ) -> tuple[float, float, float]:
    """(estimate, low, high): the percentile bootstrap (``scipy.stats.bootstrap``) of ``statistic_of(picks
    [..., S]) -> [...]`` over ``n`` scenes drawn with replacement. With ``n`` a tuple of strata sizes,
    ``statistic_of(picks_1, picks_2, ...)`` and each stratum drawn apart (a stratified bootstrap: scipy's
    independent samples); a stratum of fewer than 2 scenes is kept as it is."""
    from scipy.stats import bootstrap

    sizes = (n,) if isinstance(n, int) else tuple(n)
    samples = [np.arange(k) for k in sizes]
    estimate = float(statistic_of(*samples))
    drawn = [i for i, k in enumerate(sizes) if k >= 2]
    if not drawn:
        return estimate, estimate, estimate

    def resampled(*picks, axis=-1):
        every = [np.broadcast_to(s, (*picks[0].shape[:-1], len(s))) for s in samples]
        for i, p in zip(drawn, picks, strict=True):
            every[i] = p
        return statistic_of(*every)

    result = bootstrap(tuple(samples[i] for i in drawn), resampled, vectorized=True, axis=-1,
                       confidence_level=confidence, n_resamples=resamples, method="percentile",
                       rng=np.random.default_rng(seed))
    return estimate, float(result.confidence_interval.low), float(result.confidence_interval.high)


def _intervals(statistics_of, n: int, count: int, confidence: float, resamples: int, seed: int
               ) -> list[tuple[float, float, float]]:
    """``_interval`` of ``count`` statistics at once, ``statistics_of(picks [..., S]) -> [count, ...]``: one
    ``scipy.stats.bootstrap`` call, every statistic on the same resamples (those ``_interval`` draws with this
    seed for each alone: the same bounds, to the last bits of the percentile's arithmetic)."""
    from scipy.stats import bootstrap

    index = np.arange(n)
    estimates = np.asarray(statistics_of(index), np.float64).reshape(count)
    if n < 2:
        return [(float(e), float(e), float(e)) for e in estimates]
    result = bootstrap((index,), lambda picks, axis: statistics_of(picks), vectorized=True, axis=-1,
                       confidence_level=confidence, n_resamples=resamples, method="percentile",
                       rng=np.random.default_rng(seed))
    low, high = (np.asarray(b, np.float64).reshape(count) for b in result.confidence_interval)
    return [(float(e), float(lo), float(hi)) for e, lo, hi in zip(estimates, low, high, strict=True)]


def _stacked_confusions(sets: Sequence[Sequence[tuple[np.ndarray, np.ndarray]]], num_classes: int, what: str
                        ) -> np.ndarray:
    """[S, k, M + 1, M + 1]: the scenes' confusion matrices of ``k`` label sets over the same S scenes."""
    counts = {len(per_scene) for per_scene in sets}
    if len(counts) > 1:
        raise ValueError(f"{what}: the label sets cover {sorted(counts)} scenes; give each the same scenes")
    return np.stack([_scene_confusions(per_scene, num_classes) for per_scene in sets], axis=1)


def scene_intervals(sets: Sequence[Sequence[tuple[np.ndarray, np.ndarray]]], num_classes: int,
                    statistic: str = "f1", confidence: float = 0.95, resamples: int = 2000, seed: int = 0
                    ) -> list[tuple[float, float, float]]:
    """``scene_interval`` of several label sets of the same scenes (e.g. a row's labels after each move) in one
    bootstrap: [(estimate, low, high)] per set, as ``scene_interval`` gives each."""
    if not sets:
        return []
    cms = _stacked_confusions(sets, num_classes, "scene_intervals")
    return _intervals(lambda picks: np.moveaxis(confusion_scores(_resampled_sum(cms, picks))[statistic], -1, 0),
                      len(cms), len(sets), confidence, resamples, seed)


def paired_differences(pairs: Sequence[tuple[Sequence[tuple[np.ndarray, np.ndarray]],
                                             Sequence[tuple[np.ndarray, np.ndarray]]]], num_classes: int,
                       statistic: str = "f1", confidence: float = 0.95, resamples: int = 2000, seed: int = 0
                       ) -> list[tuple[float, float, float]]:
    """``paired_difference`` of several pairs (a, b) of label sets of the same scenes in one bootstrap:
    [(estimate, low, high)] per pair, as ``paired_difference`` gives each."""
    if not pairs:
        return []
    a = _stacked_confusions([x for x, _ in pairs], num_classes, "paired_differences")
    b = _stacked_confusions([y for _, y in pairs], num_classes, "paired_differences")
    if len(a) != len(b):
        raise ValueError(f"paired_differences: {len(a)} and {len(b)} scenes; pair the same ones")

    def differences(picks):
        return np.moveaxis(confusion_scores(_resampled_sum(a, picks))[statistic]
                           - confusion_scores(_resampled_sum(b, picks))[statistic], -1, 0)

    return _intervals(differences, len(a), len(pairs), confidence, resamples, seed)


def scene_interval(per_scene: Sequence[tuple[np.ndarray, np.ndarray]], num_classes: int, statistic: str = "f1",
                   confidence: float = 0.95, resamples: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """(estimate, low, high): a ``statistic`` of ``Scores`` over all scenes pooled and its percentile bootstrap
    interval, resampling whole scenes (objects of one scene share occlusions and a camera path;
    ``scipy.stats.bootstrap``). per_scene: [(true [n_s], predicted [n_s])] per scene."""
    cms = _scene_confusions(per_scene, num_classes)
    return _interval(lambda picks: confusion_scores(_resampled_sum(cms, picks))[statistic], len(cms), confidence,
                     resamples, seed)


def paired_difference(per_scene_a: Sequence[tuple[np.ndarray, np.ndarray]],
                      per_scene_b: Sequence[tuple[np.ndarray, np.ndarray]], num_classes: int, statistic: str = "f1",
                      confidence: float = 0.95, resamples: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """(estimate, low, high) of statistic(a) - statistic(b) for two policies run on the same scenes, with a
    paired bootstrap: each resample draws scenes and scores both policies on them."""
    if len(per_scene_a) != len(per_scene_b):
        raise ValueError(f"paired_difference: {len(per_scene_a)} and {len(per_scene_b)} scenes; pair the same ones")
    a, b = _scene_confusions(per_scene_a, num_classes), _scene_confusions(per_scene_b, num_classes)
    return _interval(lambda picks: (confusion_scores(_resampled_sum(a, picks))[statistic]
                                    - confusion_scores(_resampled_sum(b, picks))[statistic]),
                     len(a), confidence, resamples, seed)


SHARE_UNDEFINED = 1e6  # ``share_of_gap`` where the oracle does not lead the base


def share_of_gap(policy: Sequence[tuple[np.ndarray, np.ndarray]], base: Sequence[tuple[np.ndarray, np.ndarray]],
                 oracle: Sequence[tuple[np.ndarray, np.ndarray]], num_classes: int, statistic: str = "f1",
                 confidence: float = 0.95, resamples: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """(estimate, low, high) of (s(policy) - s(base)) / (s(oracle) - s(base)): the share of the oracle's lead over
    ``base`` that ``policy`` closes (1: all of it, 0: none, below 0: worse than ``base``), for three label sets of
    the same scenes, with a scene bootstrap (each resample draws scenes and scores all three on them). Where the
    oracle does not lead ``base`` (ties or trails it) the share is not defined: ``SHARE_UNDEFINED`` (a bound
    there says that more than the interval's tail of the resamples have no lead to close). Shares are clipped to
    +-``SHARE_UNDEFINED``."""
    cms = _stacked_confusions([policy, base, oracle], num_classes, "share_of_gap")

    def share(picks):
        s = confusion_scores(_resampled_sum(cms, picks))[statistic]  # [..., 3]: policy, base, oracle
        return _share_ratio(s[..., 0] - s[..., 1], s[..., 2] - s[..., 1])

    return _interval(share, len(cms), confidence, resamples, seed)


def _share_ratio(gain: np.ndarray, lead: np.ndarray) -> np.ndarray:
    """gain / lead clipped to +-``SHARE_UNDEFINED``, and ``SHARE_UNDEFINED`` where there is no lead (<= 0)."""
    ratio = gain / np.where(lead > 0, lead, 1.0)
    return np.where(lead > 0, np.clip(ratio, -SHARE_UNDEFINED, SHARE_UNDEFINED), SHARE_UNDEFINED)


def share_of_gap_all_scenes(policy: Sequence[tuple[np.ndarray, np.ndarray]],
                            base: Sequence[tuple[np.ndarray, np.ndarray]],
                            oracle: Sequence[tuple[np.ndarray, np.ndarray]],
                            oracle_base: Sequence[tuple[np.ndarray, np.ndarray]], inside: np.ndarray,
                            num_classes: int, statistic: str = "f1", confidence: float = 0.95, resamples: int = 2000,
                            seed: int = 0) -> tuple[float, float, float]:
    """(estimate, low, high) of the share of the oracle's lead that the policy closes, the policy's lead measured
    on every scene: (s(policy) - s(base)) over all N scenes / (s(oracle) - s(oracle_base)) over the K of them the
    oracle ran. ``policy``, ``base``: N scenes; ``oracle`` and ``oracle_base`` (base's labels in the oracle's
    episodes): the K scenes where ``inside: [N]`` is true, in their order. An oracle row is costly, so it runs on
    a subset; ``share_of_gap`` on that subset alone carries the subset's draw of the policy's lead as well.
    The bootstrap is stratified: each resample draws K scenes from the oracle's and N - K from the others
    (``_interval``'s strata), the oracle's scenes the same in both terms; fewer than 2 others are kept as they
    are. All N inside: ``share_of_gap`` of the policy on the oracle's episodes, where those are all the episodes.
    Shares are clipped and undefined as there."""
    inside = np.asarray(inside, bool)
    if inside.shape != (len(policy),) or len(base) != len(policy):
        raise ValueError(f"share_of_gap_all_scenes: policy, base and inside must cover the same scenes "
                         f"({len(policy)}, {len(base)}, {inside.shape})")
    if not int(inside.sum()) == len(oracle) == len(oracle_base):
        raise ValueError(f"share_of_gap_all_scenes: inside marks {int(inside.sum())} scenes, the oracle has "
                         f"{len(oracle)} and its base {len(oracle_base)}")
    cms = _stacked_confusions([policy, base], num_classes, "share_of_gap_all_scenes")  # [N, 2, M + 1, M + 1]
    in_cms, out_cms = cms[inside], cms[~inside]
    there_cms = _stacked_confusions([oracle, oracle_base], num_classes, "share_of_gap_all_scenes")  # [K, 2, ...]

    def share(picks_in, picks_out):
        s = confusion_scores(_resampled_sum(in_cms, picks_in) + _resampled_sum(out_cms, picks_out))[statistic]
        there = confusion_scores(_resampled_sum(there_cms, picks_in))[statistic]
        return _share_ratio(s[..., 0] - s[..., 1], there[..., 0] - there[..., 1])

    if len(in_cms) < 2:  # (as share_of_gap: no interval)
        estimate = float(share(np.arange(len(in_cms)), np.arange(len(out_cms))))
        return estimate, estimate, estimate
    return _interval(share, (len(in_cms), len(out_cms)), confidence, resamples, seed)


def format_difference(estimate: float, low: float, high: float) -> str:
    """``"+0.012 [-0.004, +0.031]"``: a paired difference and its interval at three decimals; a bound that is
    not 0 but rounds to it gets two significant digits (``+2.1e-04``), so that a reader can check on which
    side of 0 the interval lies."""
    def signed(x: float) -> str:
        return f"{x:+.1e}" if x != 0 and round(x, 3) == 0 else f"{x:+.3f}"

    return f"{estimate:+.3f} [{signed(low)}, {signed(high)}]"


def surface_coverage(model_points: np.ndarray, fused_points: np.ndarray, radius: float = 0.005) -> float:
    """The share of an object's posed surface samples (``model_points: [S, 3]`` world, m) within ``radius``
    of the fused surface (``fused_points: [P, 3]``): how much of it the reconstruction has seen."""
    model_points, fused_points = np.asarray(model_points, np.float64), np.asarray(fused_points, np.float64)
    if not len(model_points):
        return 0.0
    if not len(fused_points):
        return 0.0
    distance, _ = cKDTree(fused_points).query(model_points, distance_upper_bound=radius)
    return float(np.mean(np.isfinite(distance)))


def path_length(positions: np.ndarray) -> float:
    """Metres travelled through the camera positions ``[T, 3]`` in order."""
    positions = np.asarray(positions, np.float64)
    return float(np.sum(np.linalg.norm(np.diff(positions, axis=0), axis=-1))) if len(positions) > 1 else 0.0
