"""An episode built from a run's settings: the one owner of the wiring spec + classifier + model library ->
``active.Episode`` (commands, experiments, benchmarks, tests and notebooks build episodes here).

    settings = ActiveConfig(episode=EpisodeConfig(policy="vis_occl"))
    episode = make_episode(settings, object_set, intrinsics, table_height)
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

from jaxcls.episode.active import Episode, EpisodeConfig
from jaxcls.geometry import Intrinsics
from jaxcls.perception import pointnet
from jaxcls.perception.refine import ModelLibrary, RefineConfig, library_models
from jaxcls.perception.settings import PerceptionConfig, ShapeConfig, Spec
from jaxcls.planning import learned
from jaxcls.planning.nbv import NBVConfig
from jaxcls.world.objects import ObjectSet


def episode_perception() -> PerceptionConfig:
    """Perception as a move runs it: segments of 256 points into PointNet (strided from the segment; GR reads
    256 too), as accurate as 1024 on in-scene segments (0.876 against 0.872, experiments/classify_stability.py,
    BENCHMARKS.md) at a quarter of the time."""
    return PerceptionConfig(shapes=ShapeConfig(points_per_segment=256))


def episode_refine() -> RefineConfig:
    """GR as a move runs it: of each candidate class only the model nearest the segment in height, 2 yaws from
    the yaw head's estimate (its symmetric copy or one ring; weights without a yaw head: 2 evenly spaced yaws,
    with a warning, ``refine.yaw_source=auto``), the best of them finished alone, pruning's rho
    from 8 neighbours per sample: ~8x less work than ``RefineConfig()`` with 4 models per class and as
    accurate in episodes (RESULTS.md, the move's GR settings); the class by PointNet's probability x rho
    (``decision="product"``): on 30 held-out scenes the paper's argmax rho (Eq. 3, ``refine.decision=rho``)
    costs 0.068 F1 after one view, 0.028 after five."""
    return RefineConfig(yaw_source="auto", hypotheses=2, prune_per="class", prune_neighbours=8,
                        decision="product", models_per_class=1)


def episode_nbv() -> NBVConfig:
    """View choice as a move runs it: the 16 nearest viewpoints as candidates (about 12 of the paper's 100 lie
    within r = 0.5 m; the others are masked anyway), half the visibility work of 32."""
    return NBVConfig(max_candidates=16)


@dataclasses.dataclass(frozen=True)
class ActiveConfig:
    """The blocks of an active run besides the world: ``episode``, ``perception``, ``refine``, ``nbv`` and the
    classifier's weights (``classifier``: a ``.msgpack`` path, "" = the shipped weights)."""

    classifier: str = ""
    episode: EpisodeConfig = dataclasses.field(default_factory=EpisodeConfig)
    perception: PerceptionConfig = dataclasses.field(default_factory=episode_perception)
    refine: RefineConfig = dataclasses.field(default_factory=episode_refine)
    nbv: NBVConfig = dataclasses.field(default_factory=episode_nbv)

    def active_config(self) -> ActiveConfig:
        """Just these blocks of a command's config (whose schema extends this one)."""
        return ActiveConfig(**{f.name: getattr(self, f.name) for f in dataclasses.fields(ActiveConfig)})


@functools.lru_cache(maxsize=8)
def _library(object_set: ObjectSet, kind: str, split: str, icp_config) -> ModelLibrary:
    return ModelLibrary.build(library_models(object_set, kind, split), object_set.classes, icp_config)


def model_library(object_set: ObjectSet, refine: RefineConfig, scene_split: str = "test") -> ModelLibrary:
    """GR's models for ``object_set`` (``refine.library``: the scenes' instances or the training ones),
    built once per set and settings in a process."""
    return _library(object_set, refine.library, scene_split, refine.icp)


def load_classifier(path: str, object_set: ObjectSet, source: str = "classifier") -> pointnet.Classifier:
    """The weights at ``path`` ("" = shipped), refused (ValueError naming the file) unless trained on
    ``object_set``'s classes."""
    classifier = pointnet.load_classifier(path or None)
    try:
        classifier.check_classes(object_set.classes, f"object set {object_set.name!r}")
    except ValueError as e:
        raise ValueError(f"{path or 'shipped weights'} ({source}): {e}") from None
    return classifier


def make_episode(settings: ActiveConfig, object_set: ObjectSet, intrinsics: Intrinsics, table_height: float,
                 classifier: pointnet.Classifier | None = None, scene_split: str = "test") -> Episode:
    """The episode of ``settings`` for scenes of ``object_set`` seen by ``intrinsics`` over a table at
    ``table_height`` (m). ``classifier`` skips loading ``settings.classifier``."""
    classifier = classifier or load_classifier(settings.classifier, object_set)
    spec = Spec.create(settings.perception, intrinsics, table_height, classifier)
    return Episode.create(spec, model_library(object_set, settings.refine, scene_split), settings.episode,
                          settings.refine, settings.nbv, policy_weights(settings.nbv))


def policy_weights(nbv_config: NBVConfig) -> Any:
    """The learned policy's weights named by ``nbv.learned.weights`` (``learned.load``: checked against the
    planner's candidate count), None where none is named."""
    if not nbv_config.learned.weights:
        return None
    return learned.load(nbv_config.learned.weights, nbv_config.max_candidates)[0]
