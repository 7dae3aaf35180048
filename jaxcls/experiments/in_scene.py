"""PointNet where the loop uses it: segments of cluttered scenes, after 1, 3, 5, 10 fused views
(``experiments/classify_in_scene.py`` is its command line; ``experiments/calibrate.py`` and
``experiments/classify_stability.py`` use its config and evaluation).

For each world of the config and each scene seed, the camera walks a random path over the view hemisphere (a
random start, then a random unvisited candidate within ``nbv.radius`` of the current view, the
paper's move), and every frame goes through ``perception.observe``. After the configured view counts each
segment is labelled with its majority ground-truth object (``metrics.segment_truth``) and its purity recorded.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
from scipy.special import softmax
from tqdm.auto import tqdm

from jaxcls import metrics, perception
from jaxcls.config import bounded, check_bounds
from jaxcls.perception import pointnet
from jaxcls.perception.settings import PerceptionConfig
from jaxcls.planning import nbv
from jaxcls.world import WorldConfig, make_world
from jaxcls.world.dataset import scene_key, scene_seeds
from jaxcls.world.objects import object_set_from_config

SMALL_SEGMENT = 256  # points: segments smaller than this are reported apart among the errors


@dataclasses.dataclass(frozen=True)
class InSceneConfig:
    """``experiments/classify_in_scene.py``: which worlds, how many scenes and paths, which weights."""

    out_dir: str = "runs/classify_in_scene"
    seed: int = 0
    scenes: int = bounded(10, ge=1)  # per world
    paths: int = bounded(2, ge=1)  # random view paths per scene
    views: tuple[int, ...] = bounded((1, 3, 5, 10), ge=1)  # fused views after which segments are scored
    purity: float = bounded(0.8, ge=0.0, le=1.0)  # segments below this share of their majority object: apart
    weights: dict[str, str] = dataclasses.field(default_factory=lambda: {"shipped": ""})  # "" = shipped
    worlds: dict[str, WorldConfig] = dataclasses.field(default_factory=dict)
    perception: PerceptionConfig = dataclasses.field(default_factory=PerceptionConfig)

    def __post_init__(self) -> None:
        check_bounds(self)
        if not self.worlds:
            raise ValueError("worlds: name at least one world (see jaxcls/configs/classify_in_scene.yaml)")


def evaluate(config: InSceneConfig, classifiers: dict[str, pointnet.Classifier],
             show_progress: bool = True) -> dict[str, list[dict]]:
    """Per set of weights, one record per segment that belongs to a target object: world, scene, path,
    views, true and predicted class, confidence (calibrated, if the weights are), purity, size,
    uncalibrated logits. Every set of weights classifies the same segments (each scene is observed once)."""
    records = {name: [] for name in classifiers}
    for world_name, world_config in config.worlds.items():
        object_set = object_set_from_config(world_config.objects)
        for name, classifier in classifiers.items():
            classifier.check_classes(object_set.classes, f"world {world_name!r} (weights {name!r})")
        seeds = scene_seeds(config.seed, config.scenes)
        for s in tqdm(range(config.scenes), desc=world_name, disable=not show_progress):
            world = make_world(world_config, seeds[s], object_set=object_set)
            owners = metrics.PointOwners(world.scene, world.models)
            target = np.array([o.target for o in world.scene.objects])
            label = np.array([object_set.label(o.class_name) for o in world.scene.objects])
            # No classifier in the spec: the segments are classified once below, logits first.
            spec = perception.Spec.create(config.perception, world.intrinsics, world.table_height)
            rng = np.random.default_rng([config.seed, s])
            for p in range(config.paths):
                path = nbv.random_walk(rng, world.viewpoints, max(config.views))
                depth, T_wc, _, _ = world.measure(jax.random.fold_in(scene_key(config.seed, s), p), path)
                state = perception.init_state(spec)
                for k, (d, T) in enumerate(zip(depth, T_wc, strict=True), start=1):
                    state = perception.observe(spec, state, d, T)
                    if k not in config.views:
                        continue
                    seg = state.segments
                    pts, mask = np.asarray(seg.points), np.asarray(seg.mask)
                    truth = metrics.segment_truth(owners(pts.reshape(-1, 3), mask.reshape(-1)).reshape(mask.shape),
                                                  mask)
                    scored = [n for n in np.flatnonzero((truth.object >= 0) & (truth.size > 0))
                              if target[truth.object[n]]]
                    for name, classifier in classifiers.items():
                        scores = np.asarray(pointnet.logits(classifier, seg.points, seg.mask))
                        probs = softmax(scores / classifier.temperature, axis=1)  # what pointnet.classify gives
                        records[name] += [{
                            "world": world_name, "scene": s, "path": p, "views": k, "object": int(truth.object[n]),
                            "true": int(label[truth.object[n]]), "predicted": int(probs[n].argmax()),
                            "confidence": float(probs[n].max()), "purity": float(truth.purity[n]),
                            "size": int(truth.size[n]), "logits": scores[n].round(4).tolist()} for n in scored]
    return records


def confusion(rows: list[dict], classes: tuple[str, ...]) -> np.ndarray:
    """[M, M] counts of (true, predicted) classes of the records ``rows``."""
    from sklearn.metrics import confusion_matrix

    return confusion_matrix([r["true"] for r in rows], [r["predicted"] for r in rows], labels=np.arange(len(classes)))
