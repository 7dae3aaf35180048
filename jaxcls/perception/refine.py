"""Geometric refinement (GR, paper Eq. 2-4): every segment's candidate classes are checked by registering
their CAD models onto the segment; the best-fitting candidate becomes the segment's class and its aligned
pose the segment's pose.

    c* = argmax_{c in top-k(p)} rho_c                 (Eq. 3; rho_c: the best ratio over c's models, Eq. 2)
    T* = the registration of c*'s best model          (Eq. 4, model-to-world)

``ModelLibrary.build`` stacks the models once (host side): each one's ``icp.Target`` (samples, normals,
closest-sample grid), its class, and which models stand for each class. ``refine`` runs every (segment,
candidate class, model, yaw hypothesis) registration in ONE jitted, vmapped call, in two stages: all
``hypotheses`` initial yaws for ``prune_after`` iterations (``icp.align``, the ICP alone), then, per
(segment, model), the one with the best rho for the remaining iterations (the issue's lever against 8x
the work). It compiles once per library shape and config; ``refine_jit`` is the module-level jit.

Initial poses: ``pose.initial_poses`` (the model upright on the table under the segment's centroid, turned
by ``hypotheses`` evenly spaced yaws).
"""

from __future__ import annotations

import dataclasses
import enum
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxcls.config import bounded, check_bounds
from jaxcls.geometry import invert_rigid
from jaxcls.math import safe_div
from jaxcls.perception import icp, pose

if TYPE_CHECKING:  # perception reads models, it does not import the world
    from jaxcls.world.objects import ObjectModel, ObjectSet



class LibraryKind(enum.StrEnum):
    """Which models stand for a class: the instances the scenes are drawn from (the paper's "a CAD model
    for each object class") or the training instances only (the scene's shapes unseen)."""

    known = "known"
    category = "category"


class YawSource(enum.StrEnum):
    """Where the initial yaws come from: ``hypotheses``, evenly spaced over a full turn (a); ``learned``,
    around the classifier's yaw-head estimate, its symmetric copies, then ``yaw_spread`` apart (b; needs
    weights with a yaw head); ``auto``, learned with a yaw head, else hypotheses (``RefineConfig.resolve``,
    which ``Episode.create`` calls: what ran is the resolved choice)."""

    hypotheses = "hypotheses"
    learned = "learned"
    auto = "auto"


# What the best hypothesis is kept per after pruning: each (segment, model), or each (segment, candidate
# class) with its best (model, yaw). (Built by call: ``class`` is a keyword, and YAML spells it so.)
PrunePer = enum.StrEnum("PrunePer", {"model": "model", "class": "class"})


class Decision(enum.StrEnum):
    """The refined class of a segment: ``rho``, argmax rho over the candidates (the paper's Eq. 3);
    ``product``, argmax of PointNet's probability times rho (the prior's confidence weighs in: a partial
    segment that another class's model happens to fit as well no longer flips a confident prior)."""

    rho = "rho"
    product = "product"

    def scores(self, rho: jax.Array, prior: jax.Array) -> jax.Array:
        """[..., k] what the candidates are ranked by: their ``rho`` [..., k], times PointNet's probability of
        each candidate ``prior`` [..., k] under ``product``."""
        return rho * prior if self is Decision.product else rho


@dataclasses.dataclass(frozen=True)
class RefineConfig:
    """GR settings: the ICP (``icp:``), how many candidate classes, initial yaws and which models."""

    # 256 points and 3 + 9 iterations: as accurate as 512 points and 5 + 15 on the recovery cases
    # (experiments/registration.py), 2.3x faster; rho's inlier distance 5 mm: a sharper Eq. 2 than 10 mm
    # (instances of a class differ by a few mm), the true class and instance win far more often (RESULTS.md).
    icp: icp.ICPConfig = dataclasses.field(
        default_factory=lambda: icp.ICPConfig(iterations=12, points=256, inlier_distance=0.005))
    top_k: int = bounded(3, ge=1)  # candidate classes per segment (Eq. 1's top-k)
    hypotheses: int = bounded(8, ge=1)  # initial yaws per model
    yaw_source: YawSource = YawSource.hypotheses  # where they come from (``YawSource``)
    yaw_spread: float = bounded(0.5, gt=0.0)  # rad between the rings of learned hypotheses
    prune_after: int = bounded(3, ge=1)  # iterations on every hypothesis before the best goes on (= iterations: none)
    # What the best hypothesis is kept per: "model" = each (segment, model) goes on with its best yaw (every
    # instance of a candidate class finishes), "class" = each (segment, candidate class) goes on with its best
    # (model, yaw): J times fewer full registrations with J models per class (the episode's choice).
    prune_per: PrunePer = PrunePer.model
    # The pruning rho reads this many of each sample's nearest samples (``icp.registration_ratio``'s
    # ``neighbours``; None: all of ``icp.neighbours``): a cheaper, lower estimate that ranks hypotheses alike.
    prune_neighbours: int | None = None
    decision: Decision = Decision.rho  # the refined class (``Decision``)
    # Pruning reads every k-th of the segment's ``icp.points`` points so that at most this many remain (None:
    # all): the hypotheses are only ranked there, the survivors finish on all of them.
    prune_points: int | None = None
    # Register only this many models of each candidate class (None: all): those whose height is nearest the
    # segment's (its highest point above the table; the top of an upright object is seen from the hemisphere).
    models_per_class: int | None = bounded(None, ge=1)
    # Which models stand for a class: "known" = the instances the scenes are drawn from (the paper's "a CAD
    # model for each object class"), "category" = the training instances only (the scene's shapes unseen).
    library: LibraryKind = LibraryKind.known

    def __post_init__(self) -> None:
        check_bounds(self, "refine.")
        if self.prune_after > self.icp.iterations:
            raise ValueError(f"refine.prune_after ({self.prune_after}) must be <= refine.icp.iterations "
                             f"({self.icp.iterations})")

    def resolve(self, yaw_head: bool, weights: str = "the classifier") -> RefineConfig:
        """These settings as they run with a classifier that has a yaw head or not: ``yaw_source=auto``
        becomes ``learned`` or ``hypotheses`` (with a warning saying so: ``hypotheses`` evenly spaced yaws per
        model); ``learned`` without a head is a ValueError naming ``weights`` and what to set."""
        source = self.yaw_source
        if source is YawSource.learned and not yaw_head:
            raise ValueError(f"refine.yaw_source=learned needs weights with a yaw head; {weights}: none "
                             f"(set refine.yaw_source=hypotheses, or auto, and refine.hypotheses, e.g. 8)")
        if source is YawSource.auto:
            source = YawSource.learned if yaw_head else YawSource.hypotheses
            if not yaw_head:
                warnings.warn(f"refine.yaw_source=auto: {weights}: no yaw head, so GR registers "
                              f"{self.hypotheses} evenly spaced yaws per model (refine.hypotheses)", stacklevel=2)
        return dataclasses.replace(self, yaw_source=source)


class ModelLibrary(struct.PyTreeNode):
    """The models GR registers onto, stacked to static shapes (L models, M classes, at most J per class).

    targets: ``icp.Target`` of the L models (``select(m)`` registers onto model m); centroid: [L, 3] f32
    model-frame centroid of the samples (m); class_models: [M, J] i32 the models of each class (padded
    with 0); class_mask: [M, J] bool; names: the models' names; classes: the class names (the
    classifier's order).
    """

    targets: icp.Target
    centroid: jax.Array
    class_models: jax.Array
    class_mask: jax.Array
    names: tuple[str, ...] = struct.field(pytree_node=False)
    classes: tuple[str, ...] = struct.field(pytree_node=False)

    @classmethod
    def build(cls, models: Sequence[ObjectModel], classes: Sequence[str], config: icp.ICPConfig | None = None
              ) -> ModelLibrary:
        """Stack ``models`` (host side, once). Every class of ``classes`` needs at least one model."""
        config = config or icp.ICPConfig()
        classes = tuple(classes)
        unknown = sorted({m.class_name for m in models} - set(classes))
        if unknown:
            raise ValueError(f"refine: models of classes {unknown} that the classifier does not know ({classes})")
        missing = [c for c in classes if not any(m.class_name == c for m in models)]
        if missing:
            raise ValueError(f"refine: no model for classes {missing}; every class needs one")
        samples = min(config.model_points, *(len(m.surface_points) for m in models))
        targets = [icp.model_target(m, config, samples, device=False) for m in models]
        per_class = [[i for i, m in enumerate(models) if m.class_name == c] for c in classes]
        J = max(len(p) for p in per_class)
        class_models = np.array([p + [0] * (J - len(p)) for p in per_class], np.int32)
        class_mask = np.array([[True] * len(p) + [False] * (J - len(p)) for p in per_class])
        # (NumPy on the host, then one transfer each: no program compiled or loaded to build the library)
        centroid = np.stack([t.points[0].mean(0) for t in targets])
        return cls(targets=icp.stack(targets), centroid=jax.device_put(centroid),
                   class_models=jax.device_put(class_models), class_mask=jax.device_put(class_mask),
                   names=tuple(m.name for m in models), classes=classes)


def library_models(object_set: ObjectSet, kind: LibraryKind, scene_split: str = "test") -> tuple[ObjectModel, ...]:
    """The models that stand for the classes (``RefineConfig.library``): ``known`` = the instances of the
    split the scenes are drawn from (``"train"``, ``"test"`` or ``"all"``), ``category`` = the training
    instances only."""
    if LibraryKind(kind) is LibraryKind.category:
        return tuple(object_set.train)
    return tuple(object_set.split(scene_split))


class Refinement(struct.PyTreeNode):
    """GR's answer per segment (N segments, k candidates).

    prior: [N] i32 PointNet's class (Eq. 1's argmax); candidates: [N, k] i32 its top-k classes; rho: [N, k]
    f32 the best registration ratio of each candidate's models (Eq. 2; 0 for an empty segment); refined:
    [N] i32 the class of Eq. 3; pose: [N, 4, 4] f32 model-to-world pose of Eq. 4 (identity if empty);
    model: [N] i32 the library model chosen; valid: [N] bool the segment is live: it had points to register
    (and, in an episode with the count estimated, is no part of a larger segment's object: ``explained``).
    """

    prior: jax.Array
    candidates: jax.Array
    rho: jax.Array
    refined: jax.Array
    pose: jax.Array
    model: jax.Array
    valid: jax.Array


def refine(points: jax.Array, mask: jax.Array, probs: jax.Array, library: ModelLibrary, config: RefineConfig,
           table_height: float | jax.Array = 0.0, seen_from: jax.Array | None = None, yaw: jax.Array | None = None,
           yaw_orders: jax.Array | None = None) -> Refinement:
    """GR for N segments: points [N, P, 3] world (m), mask [N, P], probs [N, M] PointNet's scores (classes
    in ``library.classes`` order); at most ``config.icp.points`` points of a segment are read, rho
    included. seen_from: optional [C, 3] camera positions for the visibility-aware rho
    (``icp.registration_ratio``). With ``config.yaw_source = "learned"``: yaw [N, M] rad the yaw head's
    estimates (``pointnet.estimate_yaw``) and yaw_orders [M] i32 their symmetry orders
    (``Classifier.yaw_orders``). Pure; see ``refine_jit``."""
    if config.yaw_source is YawSource.auto:
        raise ValueError("refine: yaw_source 'auto' must be resolved first (RefineConfig.resolve)")
    learned = config.yaw_source is YawSource.learned
    if learned and (yaw is None or yaw_orders is None):
        raise ValueError("refine: yaw_source 'learned' needs yaw [N, M] (pointnet.estimate_yaw) and yaw_orders [M]")
    # Every registration (and its rho) reads the same icp.points of each segment: sampled once, here.
    points, mask = jax.vmap(lambda p, m: icp.subsample(p, m, config.icp.points))(points, mask)
    k = min(config.top_k, probs.shape[1])
    _, candidates = jax.lax.top_k(probs, k)  # [N, k]
    models = library.class_models[candidates]  # [N, k, J]
    model_ok = library.class_mask[candidates]
    if config.models_per_class is not None and config.models_per_class < models.shape[2]:
        height = jnp.max(library.targets.points[..., 2], axis=1)  # [L] m, models stand on z = 0
        top = jnp.max(jnp.where(mask, points[..., 2], -jnp.inf), axis=1) - table_height  # [N]
        gap = jnp.where(model_ok, jnp.abs(height[models] - top[:, None, None]), jnp.inf)
        keep = jnp.argsort(gap, axis=2)[..., :config.models_per_class]
        models = jnp.take_along_axis(models, keep, axis=2)
        model_ok = jnp.take_along_axis(model_ok, keep, axis=2)
    first = dataclasses.replace(config.icp, iterations=config.prune_after)
    left = config.icp.iterations - config.prune_after  # 0: no pruning, every hypothesis runs to the end
    remaining = dataclasses.replace(config.icp, iterations=left) if left else None
    prune_stride = -(-points.shape[1] // config.prune_points) if config.prune_points else 1

    def hypotheses(n, c, m):
        """Every initial yaw of model ``m`` (class ``c``) on segment ``n`` after ``prune_after`` iterations:
        (poses [H, 4, 4], rho [H], valid [H])."""
        p, mk = points[n], mask[n]
        yaws = (pose.learned_yaws(yaw[n, c], yaw_orders[c], config.hypotheses, config.yaw_spread) if learned
                else pose.even_yaws(config.hypotheses))
        inits = pose.initial_poses(p, mk, library.centroid[m], table_height, yaws)
        p, mk = p[::prune_stride], mk[::prune_stride]
        tgt = library.targets.select(m)
        stage = jax.vmap(lambda T: icp.align(p, mk, tgt, T, first))(inits)
        # "best rho kept": fitness alone saturates on partial views
        score = jax.vmap(lambda T: icp.registration_ratio(p, mk, tgt, T, config.icp.inlier_distance, seen_from,
                                                          config.prune_neighbours)["rho"])(stage.pose)
        return stage.pose, score, stage.valid

    def finish(n, m, T, ok):
        """The best hypothesis of model ``m`` on segment ``n`` (pose ``T``) registered to the end: (rho, pose)."""
        p, mk, tgt = points[n], mask[n], library.targets.select(m)
        if remaining is not None:
            done = icp.icp(p, mk, tgt, T, remaining, seen_from)
            return done.rho, done.pose, done.valid & ok
        return icp.registration_ratio(p, mk & ok, tgt, T, config.icp.inlier_distance, seen_from)["rho"], T, ok

    # One flat vmap over the (segment, candidate, model) pairs: nested vmaps made XLA's CPU gathers ~1.6x
    # slower (benchmarks/refine.py).
    N, J = points.shape[0], models.shape[2]
    pair_segment = jnp.repeat(jnp.arange(N), k * J)
    pair_class = jnp.broadcast_to(candidates[..., None], models.shape).reshape(-1)
    poses, score, valid = jax.vmap(hypotheses)(pair_segment, pair_class, models.reshape(-1))  # [N k J, H]
    score = jnp.where(valid & model_ok.reshape(-1)[:, None], score, -1.0)
    n = jnp.arange(N)
    if config.prune_per is PrunePer.model:
        h = jnp.argmax(score, axis=1)
        pick = jnp.arange(score.shape[0])
        rho, poses, valid = jax.vmap(finish)(pair_segment, models.reshape(-1), poses[pick, h], valid[pick, h])
        rho, poses, valid = rho.reshape(models.shape), poses.reshape(*models.shape, 4, 4), valid.reshape(models.shape)
        rho = jnp.where(model_ok & valid, rho, -1.0)
        j = jnp.argmax(rho, axis=2)  # the best model of each candidate class
        class_rho = jnp.maximum(jnp.take_along_axis(rho, j[..., None], axis=2)[..., 0], 0.0)  # [N, k]
        class_pose = jnp.take_along_axis(poses, j[..., None, None, None], axis=2)[:, :, 0]  # [N, k, 4, 4]
        class_valid = jnp.any(valid & model_ok, axis=2)
    else:  # the best (model, yaw) of each (segment, candidate class) goes on alone
        H = score.shape[1]
        flat = score.reshape(N * k, J * H)
        best = jnp.argmax(flat, axis=1)
        j = (best // H).reshape(N, k)
        chosen = poses.reshape(N * k, J * H, 4, 4)[jnp.arange(N * k), best]
        ok = valid.reshape(N * k, J * H)[jnp.arange(N * k), best] & (jnp.max(flat, axis=1) >= 0)
        rho, class_pose, class_valid = jax.vmap(finish)(jnp.repeat(n, k), jnp.take_along_axis(
            models, j[..., None], axis=2).reshape(-1), chosen, ok)
        class_rho = jnp.where(class_valid, rho, 0.0).reshape(N, k)
        class_pose, class_valid = class_pose.reshape(N, k, 4, 4), class_valid.reshape(N, k)
    # Eq. 3 (ties: the higher PointNet score, the earlier candidate)
    c = jnp.argmax(config.decision.scores(class_rho, jnp.take_along_axis(probs, candidates, axis=1)), axis=1)
    segment_valid = jnp.any(class_valid, axis=1)
    chosen_j = jnp.take_along_axis(j, c[:, None], axis=1)[:, 0]
    chosen_pose = class_pose[n, c]
    prior = candidates[:, 0]
    return Refinement(prior=prior, candidates=candidates, rho=jnp.where(segment_valid[:, None], class_rho, 0.0),
                      refined=jnp.where(segment_valid, candidates[n, c], prior),
                      pose=jnp.where(segment_valid[:, None, None], chosen_pose, jnp.eye(4, dtype=points.dtype)),
                      model=jnp.where(segment_valid, models[n, c, chosen_j], -1), valid=segment_valid)


def explained(points: jax.Array, mask: jax.Array, refinement: Refinement, library: ModelLibrary, distance: float,
              share: float, sample: int) -> jax.Array:
    """[N] bool: the live segments whose points lie on a larger live segment's aligned model, ``share`` of them
    or more within ``distance`` m of its surface (the nearest of its samples at its refined pose and model): a
    second part of one object that the segmentation parted (a bowl's wall seen as two arcs), which GR's fit of
    the larger part already covers. points [N, P, 3] world (m), mask [N, P], ``refinement``: GR's answer for
    them (``refine``); ``sample`` points of a segment are read (``icp.subsample``). Larger: more points in its
    slot, ties to the lower index, so two segments never remove each other; a slot holds at most
    ``points_per_segment`` points, so two large segments tie and the lower index (the -x side) explains the
    other. Any live larger segment may explain, whatever its fit's rho. Pure; N x N lookups of ``sample``
    points."""
    sub, sub_mask = jax.vmap(lambda p, m: icp.subsample(p, m, sample))(points, mask)
    size = jnp.sum(mask, axis=1)
    N = points.shape[0]

    def on_model(j: jax.Array, i: jax.Array) -> jax.Array:
        """The share of segment j's points within ``distance`` of segment i's aligned model."""
        _, d = icp.closest(library.targets.select(jnp.maximum(refinement.model[i], 0)),
                           icp.apply_rigid(invert_rigid(refinement.pose[i]), sub[j]))
        return safe_div(jnp.sum(sub_mask[j] & (d <= distance)), jnp.sum(sub_mask[j]))

    j, i = jnp.meshgrid(jnp.arange(N), jnp.arange(N), indexing="ij")
    fraction = jax.vmap(on_model)(j.reshape(-1), i.reshape(-1)).reshape(N, N)  # [j, i]
    larger = (size[None, :] > size[:, None]) | ((size[None, :] == size[:, None]) & (i < j))
    live = refinement.valid  # (a live segment has a model: ``refine`` sets -1 only where it is not)
    return jnp.any(live[:, None] & live[None, :] & larger & (fraction >= share), axis=1)


refine_jit = jax.jit(refine, static_argnames=("config",))
refine_jit.__doc__ = "``refine`` under one ``jax.jit`` (compiled once per library shape and config)."

