"""An episode scored against its scene (the paper's Sec. 4 protocol): segments matched to the scene's objects
by Hungarian assignment on centroids (``metrics.match_objects``), the target objects' labels scored with
macro one-vs-all accuracy, precision, recall and F1 (``metrics.classification_scores``; clutter is never
scored, an unmatched target counts as wrong), and how much of each object the fused surface covers.
``target_f1`` is the target objects' F1 in JAX (a reward inside a jitted rollout), the host's number.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxcls import metrics
from jaxcls.math import linear_sum_assignment, safe_div
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


class TruthArrays(struct.PyTreeNode):
    """A ``Truth`` as arrays for JAX, padded to a static object count: centroid [K, 3] m, label [K] i32, target
    [K] bool, present [K] bool (False: padding)."""

    centroid: jax.Array
    label: jax.Array
    target: jax.Array
    present: jax.Array

    @classmethod
    def of(cls, truth: Truth, objects: int) -> TruthArrays:
        """``truth`` padded to ``objects`` objects (ValueError where it has more)."""
        K = len(truth.label)
        if K > objects:
            raise ValueError(f"TruthArrays: the scene has {K} objects, more than the {objects} padded to")
        pad = objects - K
        return cls(centroid=np.pad(np.asarray(truth.centroid, np.float32), ((0, pad), (0, 0))),
                   label=np.pad(np.asarray(truth.label, np.int32), (0, pad), constant_values=-1),
                   target=np.pad(np.asarray(truth.target, bool), (0, pad)),
                   present=np.arange(objects) < K)


def target_f1(truth: TruthArrays, centroid: jax.Array, valid: jax.Array, labels: jax.Array, num_classes: int,
              max_distance: float = metrics.MATCH_DISTANCE) -> jax.Array:
    """[] the target objects' macro F1 of segments' labels, in JAX (jit- and vmap-able): ``candidate_f1``'s
    number for one set of segments, in float32. The segments are matched to the objects by assignment on
    centroid distance (``math.linear_sum_assignment``; a dead segment only where no live one is left, then no
    match; padded objects indifferent), pairs farther than ``max_distance`` are no match, and the macro F1 runs
    over the classes that occur (``metrics.confusion_scores``). Needs K <= N (objects, padding included, at most
    the segment slots).

    centroid: [N, 3] m; valid: [N] bool; labels: [N] class index per segment."""
    K, N = truth.label.shape[0], valid.shape[0]
    if K > N:
        raise ValueError(f"target_f1: {K} objects and {N} segment slots; needs K <= N")
    distance = jnp.linalg.norm(truth.centroid[:, None, :] - centroid[None, :, :], axis=-1)  # [K, N]
    # A dead segment costs more than any assignment of live ones could save (not 1e6: float32 potentials would
    # lose the distances' digits), so the live ones are all used first.
    dead = 1.0 + K * jnp.max(jnp.where(truth.present[:, None] & valid[None, :], distance, 0.0))
    cost = jnp.where(truth.present[:, None], jnp.where(valid[None, :], distance, dead), 0.0)
    col = linear_sum_assignment(cost)
    matched = truth.present & valid[col] & (distance[jnp.arange(K), col] <= max_distance)
    predicted = jnp.where(matched, labels[col], -1)
    M = num_classes
    cm = jnp.zeros((M + 1, M + 1), jnp.float32).at[
        jnp.where(truth.label < 0, M, truth.label), jnp.where(predicted < 0, M, predicted)].add(
        (truth.target & truth.present).astype(jnp.float32))
    cm = cm.at[M, M].set(0.0)
    tp = jnp.diagonal(cm[:M, :M])
    true_count, pred_count = cm[:M, :].sum(axis=1), cm[:, :M].sum(axis=0)
    occurs = (true_count > 0) | (pred_count > 0)
    precision, recall = safe_div(tp, pred_count), safe_div(tp, true_count)
    f1 = safe_div(2 * precision * recall, precision + recall)
    return jnp.sum(jnp.where(occurs, f1, 0.0)) / jnp.maximum(jnp.sum(occurs), 1)
