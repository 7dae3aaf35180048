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
        samples = [(T[:3, :3] @ m.surface_points.T).T + T[:3, 3]
                   for m, T in zip(models, scene.object_poses(), strict=True)]
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
