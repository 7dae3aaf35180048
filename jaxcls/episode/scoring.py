"""An episode scored against its scene (the paper's Sec. 4 protocol): segments matched to the scene's objects
by Hungarian assignment on centroids (``metrics.match_objects``), the target objects' labels scored with
macro one-vs-all accuracy, precision, recall and F1 (``metrics.classification_scores``; clutter is never
scored, an unmatched target counts as wrong), and how much of each object the fused surface covers.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxcls import metrics
from jaxcls.world.objects import ObjectSet
from jaxcls.world.scenes import Scene, scene_models


@dataclasses.dataclass(frozen=True, eq=False)
class Truth:
    """What the scene holds, K objects: centroid [K, 3] m (of the posed surface samples); label [K] class
    index (-1: a clutter instance of another set); target [K] bool (False: clutter, never scored); surface:
    K arrays [S_k, 3] posed surface samples (world, m); names: the instances."""

    centroid: np.ndarray
    label: np.ndarray
    target: np.ndarray
    surface: tuple[np.ndarray, ...]
    names: tuple[str, ...]

    @classmethod
    def from_scene(cls, scene: Scene, object_set: ObjectSet) -> Truth:
        surface = scene.posed_surfaces(scene_models(scene, object_set))
        return cls(centroid=np.stack([s.mean(axis=0) for s in surface]),
                   label=np.array([object_set.label(o.class_name) for o in scene.objects]),
                   target=np.array([o.target for o in scene.objects], bool), surface=surface,
                   names=tuple(o.name for o in scene.objects))


def object_labels(truth: Truth, centroid: np.ndarray, valid: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """[..., K] the label of the segment matched to each object (-1: no segment matched it); the objects are
    matched once, for every set of labels.

    centroid: [N, 3] segment centroids (m); valid: [N] bool; labels: [..., N] class index per segment (e.g.
    [2, N]: the prior and the refined labels)."""
    match = metrics.match_objects(centroid, valid, truth.centroid)
    return np.where(match >= 0, np.asarray(labels)[..., np.maximum(match, 0)], -1)


def target_scores(truth: Truth, labels: np.ndarray, num_classes: int) -> metrics.Scores:
    """The target objects' ``metrics.Scores`` of per-object labels ``labels: [K]`` (``object_labels``)."""
    return metrics.classification_scores(truth.label[truth.target], np.asarray(labels)[truth.target], num_classes)


def candidate_f1(truth: Truth, centroid: np.ndarray, valid: np.ndarray, labels: np.ndarray, num_classes: int
                 ) -> np.ndarray:
    """[C] the target objects' macro F1 of each of C candidates' segments at once: ``target_scores(truth,
    object_labels(truth, centroid[c], valid[c], labels[c]), num_classes).f1`` for every c (the same numbers; the
    oracle scores every candidate of every run at each move).

    centroid: [C, N, 3] segment centroids (m); valid: [C, N] bool; labels: [C, N] class index per segment."""
    match = metrics.match_objects_batched(centroid, valid, truth.centroid)[:, truth.target]  # [C, Kt]
    predicted = np.where(match >= 0, np.take_along_axis(np.asarray(labels), np.maximum(match, 0), axis=1), -1)
    true = np.broadcast_to(truth.label[truth.target], predicted.shape)
    M = num_classes
    cm = np.zeros((len(predicted), M + 1, M + 1), np.int64)
    candidate = np.broadcast_to(np.arange(len(predicted))[:, None], predicted.shape)
    np.add.at(cm, (candidate, np.where(true < 0, M, true), np.where(predicted < 0, M, predicted)), 1)
    cm[:, M, M] = 0
    return metrics.confusion_scores(cm)["f1"]


def coverage(truth: Truth, fused_points: np.ndarray) -> np.ndarray:
    """[K] the share of each object's surface samples within 5 mm of the fused surface points [P, 3]."""
    return np.array([metrics.surface_coverage(s, fused_points) for s in truth.surface])
