"""Geometric refinement (paper Eq. 2-4) measured: pose recovery and class separation on rendered objects,
and what GR does to PointNet's labels on segments of cluttered scenes.

    python experiments/registration.py --config registration [key=value ...] [--out RESULTS.md]

1. **Recovery** (``objects`` scenes of one held-out built-in instance each, ``views`` = 1 and 3 fused
   views along a random hemisphere path, through ``perception.observe`` with one segment): the object's
   segment is refined with every class as a candidate (``top_k`` = all) against three libraries:
   ``instance`` (the paper's assumption: the object's class stands for its own model), ``known`` (every
   held-out instance: the right one must be found too) and ``category`` (training instances only), with
   the plain rho of Eq. 2 and the visibility-aware one (only model samples facing a camera that looked).
   The object's yaw is drawn uniformly by the scene, so the yaw hypotheses start up to 180 degrees away;
   the translation starts at the segment's centroid (its error is reported). Scored: the refined class;
   the true class's rho above every wrong class's; the chosen pose within 5 degrees (modulo the object's
   yaw symmetry) and 5 mm. Every ``refine`` variant of the config is scored on the same segments (speed
   settings against accuracy).
2. **In the scene** (``scenes`` cluttered held-out scenes, one random path each, after ``scene_views``
   views): each segment of a target object classified by every set of ``weights``, then refined (top 3,
   ``known`` library). Scored per weights: of the segments PointNet gets wrong but ranks the truth in its
   top 3, the share GR fixes; of those it gets right, the share GR breaks.

Outputs in ``out_dir``: ``results.json`` (every case) and the Markdown tables (stdout, ``--out``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import time
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxcls import io, metrics, perception, report
from jaxcls.config import bounded, check_bounds, load_config, save_config
from jaxcls.perception import pointnet, pose, refine
from jaxcls.perception.settings import PerceptionConfig
from jaxcls.planning import nbv
from jaxcls.world import WorldConfig, make_world
from jaxcls.world.dataset import scene_key, scene_seeds
from jaxcls.world.objects import object_set_from_config
from jaxcls.world.scenes import SceneConfig

ANGLE, SHIFT = 5.0, 0.005  # degrees, metres: a recovered pose
LIBRARIES = ("instance", "known", "category")  # "instance": known, the true class holding only the object's model


def _isolated() -> WorldConfig:
    return WorldConfig(scene=SceneConfig(num_objects=1, split="test"))


def _clutter() -> WorldConfig:
    return WorldConfig(scene=SceneConfig(num_objects=5, split="test"))


@dataclasses.dataclass(frozen=True)
class RegistrationConfig:
    """``experiments/registration.py``: recovery cases, cluttered scenes, weights and refine variants."""

    out_dir: str = "runs/registration"
    seed: int = 0
    objects: int = bounded(60, ge=1)  # single-object scenes (recovery)
    views: tuple[int, ...] = bounded((1, 3), ge=1)  # fused views after which the object is refined
    scenes: int = bounded(30, ge=1)  # cluttered scenes (GR in the scene)
    scene_views: tuple[int, ...] = bounded((1, 3, 5), ge=1)
    weights: dict[str, str] = dataclasses.field(default_factory=lambda: {"shipped": "", "paper": "builtin_paper"})
    yaw_weights: str = ""  # the classifier whose yaw head learned variants use ("" = the shipped default)
    refine: dict[str, refine.RefineConfig] = dataclasses.field(
        default_factory=lambda: {"default": refine.RefineConfig()})  # the first one also runs part 2
    isolated: WorldConfig = dataclasses.field(default_factory=_isolated)
    clutter: WorldConfig = dataclasses.field(default_factory=_clutter)
    perception: PerceptionConfig = dataclasses.field(default_factory=PerceptionConfig)

    def __post_init__(self) -> None:
        check_bounds(self)
        if not self.refine:
            raise ValueError("refine: name at least one RefineConfig variant")


def _walk(world, config: RegistrationConfig, spec, index: int, views: tuple[int, ...]):
    """Observe ``max(views)`` views of ``world`` along a random path; yield (views so far, state, seen
    from [max(views), 3] camera positions with NaN rows for views not yet taken)."""
    rng = np.random.default_rng([config.seed, index])
    path = nbv.random_walk(rng, world.viewpoints, max(views))
    depth, T_wc, _, _ = world.measure(scene_key(config.seed, index), path)
    state = perception.init_state(spec)
    seen = np.full((max(views), 3), np.nan, np.float32)
    for k, (d, T) in enumerate(zip(depth, T_wc, strict=True), start=1):
        state = perception.observe(spec, state, d, T)
        seen[k - 1] = T[:3, 3]
        if k in views:
            yield k, state, seen.copy()


def _truth(world, state):
    owners = metrics.PointOwners(world.scene, world.models)
    pts, mask = np.asarray(state.segments.points), np.asarray(state.segments.mask)
    return metrics.segment_truth(owners(pts.reshape(-1, 3), mask.reshape(-1)).reshape(mask.shape), mask)


def _only(library: refine.ModelLibrary, cls: int, name: str) -> refine.ModelLibrary:
    """``library`` with class ``cls`` standing for model ``name`` alone (same shapes: no recompilation)."""
    models = library.class_models.at[cls].set(library.names.index(name))
    return library.replace(class_models=models, class_mask=library.class_mask.at[cls].set(False).at[cls, 0].set(True))


def _refine(pts, mask, probs, library, rc: refine.RefineConfig, table_height, seen, yaw_head):
    """``refine_jit``, with the yaw head's estimates first for a learned variant."""
    if rc.yaw_source != "learned":
        return refine.refine_jit(pts, mask, probs, library, rc, table_height, seen)
    return refine.refine_jit(pts, mask, probs, library, rc, table_height, seen,
                             pointnet.estimate_yaw(yaw_head, pts, mask), np.asarray(yaw_head.yaw_orders, np.int32))


def _timed(fn, *args, **kwargs):
    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args, **kwargs))
    return out, time.perf_counter() - start


def recovery(config: RegistrationConfig, classifier: pointnet.Classifier, show_progress: bool = True) -> list[dict]:
    """One record per (case, refine variant, library, rho kind): see the module docstring (part 1)."""
    object_set = object_set_from_config(config.isolated.objects)
    classes = classifier.classes
    classifier.check_classes(object_set.classes, "registration: isolated world")
    libraries = {(v, kind): refine.ModelLibrary.build(refine.library_models(object_set, kind), classes, rc.icp)
                 for v, rc in config.refine.items() for kind in ("known", "category")}
    yaw_head = (pointnet.load_classifier(config.yaw_weights or None)
                if any(rc.yaw_source == "learned" for rc in config.refine.values()) else None)
    # One object on the table: one segment (K-means would split it into num_segments pieces).
    one = dataclasses.replace(config.perception, shapes=dataclasses.replace(config.perception.shapes, num_segments=1))
    records = []
    for s, seed in enumerate(tqdm(scene_seeds(config.seed, config.objects), desc="recovery",
                                  disable=not show_progress)):
        world = make_world(config.isolated, seed, object_set=object_set)
        spec = perception.Spec.create(one, world.intrinsics, world.table_height, classifier)
        model, truth_pose = world.models[0], world.scene.object_poses()[0]
        true_class = classes.index(model.class_name)
        for k, state, seen in _walk(world, config, spec, s, config.views):
            truth = _truth(world, state)
            sizes = np.where(truth.object == 0, truth.size, -1)
            n = int(np.argmax(sizes))
            if sizes[n] < 3:
                continue
            pts, mask = state.segments.points[n:n + 1], state.segments.mask[n:n + 1]
            start = np.asarray(pose.initial_poses(pts[0], mask[0], model.surface_points.mean(0), world.table_height,
                                                  np.array([world.scene.objects[0].yaw], np.float32)))
            base = {"scene": s, "views": k, "class": model.class_name, "instance": model.name,
                    "symmetry": model.yaw_symmetry, "size": int(truth.size[n]),
                    "start_shift": float(np.linalg.norm(start[0, :3, 3] - truth_pose[:3, 3]))}
            uniform = np.full((1, len(classes)), 1.0 / len(classes), np.float32)
            for (variant, kind), library in [*libraries.items(), *(
                    ((v, "instance"), _only(libraries[v, "known"], true_class, model.name)) for v in config.refine)]:
                rc = dataclasses.replace(config.refine[variant], top_k=len(classes))
                for aware in (False, True):
                    out, seconds = _timed(_refine, pts, mask, uniform, library, rc, world.table_height,
                                          seen if aware else None, yaw_head)
                    rho = np.zeros(len(classes))
                    rho[np.asarray(out.candidates[0])] = np.asarray(out.rho[0])
                    angle, shift = metrics.pose_error(np.asarray(out.pose[0]), truth_pose, model.yaw_symmetry)
                    records.append({**base, "variant": variant, "library": kind, "aware": aware,
                                    "refined": classes[int(out.refined[0])], "rho": rho.round(4).tolist(),
                                    "beats": bool(rho[true_class] > np.delete(rho, true_class).max()),
                                    "margin": float(rho[true_class] - np.delete(rho, true_class).max()),
                                    "model": library.names[int(out.model[0])], "angle": angle, "shift": shift,
                                    "seconds": seconds})
    return records


def in_scene(config: RegistrationConfig, classifiers: dict[str, pointnet.Classifier],
             show_progress: bool = True) -> list[dict]:
    """One record per (segment of a target object, views, weights): PointNet's top 3 and GR's class."""
    object_set = object_set_from_config(config.clutter.objects)
    classes = next(iter(classifiers.values())).classes
    rc = next(iter(config.refine.values()))
    library = refine.ModelLibrary.build(refine.library_models(object_set, "known"), classes, rc.icp)
    records = []
    for s, seed in enumerate(tqdm(scene_seeds(config.seed, config.scenes), desc="in the scene",
                                  disable=not show_progress)):
        world = make_world(config.clutter, seed, object_set=object_set)
        spec = perception.Spec.create(config.perception, world.intrinsics, world.table_height)
        for k, state, seen in _walk(world, config, spec, 10_000 + s, config.scene_views):
            truth = _truth(world, state)
            scored = [n for n in np.flatnonzero((truth.object >= 0) & (truth.size > 0))
                      if world.scene.objects[truth.object[n]].target]
            for name, classifier in classifiers.items():
                probs = pointnet.classify(classifier, state.segments.points, state.segments.mask)
                out = {aware: refine.refine_jit(state.segments.points, state.segments.mask, probs, library, rc,
                                                world.table_height, seen if aware else None)
                       for aware in (False, True)}
                top = np.asarray(out[False].candidates)
                p = np.take_along_axis(np.asarray(probs), top, axis=1)
                records += [{"scene": s, "views": k, "weights": name, "purity": float(truth.purity[n]),
                             "true": object_set.class_index(world.scene.objects[truth.object[n]].class_name),
                             "top": top[n].tolist(), "probs": p[n].round(4).tolist(),
                             "rho": np.asarray(out[False].rho[n]).round(4).tolist(),
                             "rho_aware": np.asarray(out[True].rho[n]).round(4).tolist(),
                             "refined": int(out[False].refined[n]), "refined_aware": int(out[True].refined[n])}
                            for n in scored]
    return records


def _rate(hits: list[bool]) -> str:
    return f"{np.mean(hits):.3f} ({sum(hits)}/{len(hits)})" if hits else ""


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="registration", help="a path or a shipped config name")
    parser.add_argument("--out", help="append the tables to this Markdown file")
    parser.add_argument("--parts", nargs="*", choices=("recovery", "scenes"), default=["recovery", "scenes"],
                        help="parts to run; the others' records are read back from out_dir/results.json (none: "
                             "only the tables)")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_intermixed_args(argv)
    config = load_config(RegistrationConfig, args.config, args.overrides)
    out = Path(config.out_dir)
    save_config(config, out / "config.yaml")
    classifiers = {name: pointnet.load_classifier(path or None) for name, path in config.weights.items()}
    previous = json.loads((out / "results.json").read_text()) if (out / "results.json").is_file() else {}
    cases = (recovery(config, next(iter(classifiers.values()))) if "recovery" in args.parts
             else previous.get("recovery", []))
    scene_records = in_scene(config, classifiers) if "scenes" in args.parts else previous.get("in_scene", [])
    if args.parts:
        io.write_json(out / "results.json", {"config": dataclasses.asdict(config), "recovery": cases,
                                                "in_scene": scene_records})

    def recovered(r):  # the object's own model, within 5 degrees (modulo symmetry) and 5 mm
        return r["model"] == r["instance"] and r["angle"] <= ANGLE and r["shift"] <= SHIFT

    rows = []
    for variant in config.refine:
        for kind in LIBRARIES:
            for aware in (False, True):
                for k in config.views:
                    mine = [r for r in cases if (r["variant"], r["library"], r["aware"], r["views"])
                            == (variant, kind, aware, k)]
                    if not mine:
                        continue
                    asym = [r for r in mine if r["symmetry"] == 1]
                    posed = kind != "category"  # a training instance cannot be posed onto an unseen shape
                    rows.append((variant, kind, "visibility-aware" if aware else "plain", k, len(mine),
                                 _rate([r["refined"] == r["class"] for r in mine]),
                                 _rate([r["beats"] for r in mine]),
                                 f"{statistics.median(r['margin'] for r in mine):+.3f}",
                                 _rate([r["model"] == r["instance"] for r in mine]) if posed else "",
                                 _rate([recovered(r) for r in asym]) if posed else "",
                                 _rate([recovered(r) for r in mine]) if posed else "",
                                 f"{1000 * statistics.median(r['seconds'] for r in mine):.0f}"))
    starts = [r["start_shift"] for r in cases if r["variant"] == next(iter(config.refine)) and
              r["library"] == "known" and not r["aware"]]
    report.publish(report.section(
        "Geometric refinement: recovery of rendered held-out objects", argv,
        ("refine variant", "library", "rho", "views", "cases", "class right", "true rho beats every wrong one",
         "median margin (true rho - best wrong)", "own model chosen",
         f"pose within {ANGLE:g} deg / {SHIFT * 1000:g} mm, no-symmetry objects", "same, all objects",
         "median ms per case"), rows,
        intro=f"{config.objects} single-object scenes; every class is a candidate (all classes x their models x "
              "yaw hypotheses per case). Libraries: `instance` = the paper's assumption (the object's class stands "
              "for its own model; every other class for all its held-out instances), `known` = every held-out "
              "instance (the right one must be found too), `category` = training instances only. Start: the "
              f"segment's centroid (translation error median {1000 * np.median(starts):.1f} mm, 95th percentile "
              f"{1000 * np.percentile(starts, 95):.1f} mm) and yaws evenly spaced from 0 (the object's own yaw is "
              "uniform: up to 180 degrees off). A pose counts when the object's own model was chosen."), args.out)
    per_class = []
    first = next(iter(config.refine))
    for cls in sorted({r["class"] for r in cases}):
        row = [cls]
        mine = {kind: [r for r in cases if r["class"] == cls and r["variant"] == first and r["library"] == kind
                       and not r["aware"]] for kind in LIBRARIES}
        row += [len(mine["instance"]), _rate([recovered(r) for r in mine["instance"]]),
                _rate([r["beats"] for r in mine["instance"]]), _rate([r["beats"] for r in mine["known"]]),
                _rate([r["model"] == r["instance"] for r in mine["known"]]),
                _rate([r["beats"] for r in mine["category"]]), mine["instance"][0]["symmetry"]]
        per_class.append(row)
    report.publish(report.section(
        f"Geometric refinement: recovery per class (variant {first!r}, plain rho, all view counts)", argv,
        ("class", "cases", "instance: pose recovered", "instance: true rho beats", "known: true rho beats",
         "known: own model chosen", "category: true rho beats", "yaw symmetry (0 = continuous)"), per_class),
        args.out)
    if scene_records:
        rows = []
        for name in config.weights:
            for aware in (False, True):
                key = "refined_aware" if aware else "refined"
                for k in config.scene_views:
                    mine = [r for r in scene_records if r["weights"] == name and r["views"] == k]
                    wrong = [r for r in mine if r["top"][0] != r["true"] and r["true"] in r["top"]]
                    right = [r for r in mine if r["top"][0] == r["true"]]
                    rows.append((name, "visibility-aware" if aware else "plain", k, len(mine),
                                 f"{np.mean([r['top'][0] == r['true'] for r in mine]):.3f}",
                                 f"{np.mean([r[key] == r['true'] for r in mine]):.3f}",
                                 _rate([r[key] == r["true"] for r in wrong]),
                                 _rate([r[key] != r["true"] for r in right])))
        report.publish(report.section(
            "Geometric refinement on segments of cluttered scenes", argv,
            ("weights", "rho", "views", "segments", "PointNet accuracy", "after GR (Eq. 3)",
             "fixed: wrong, truth in top 3", "broken: right before GR"), rows,
            intro=f"{config.scenes} held-out synthetic scenes, one random path each; every segment of a target "
                  f"object; GR variant {first!r}, known library (every held-out instance)."), args.out)
    if scene_records:
        _uncertainty_table(scene_records, config, argv, args.out)
    print(json.dumps({"out_dir": str(out)}))


def _uncertainty_table(records: list[dict], config: RegistrationConfig, argv, out) -> None:
    """Which per-segment uncertainty predicts a wrong refined class (for the uncertainty-weighted NBV
    policy): AUROC of each score, over the in-scene records of every set of weights."""
    from sklearn.metrics import roc_auc_score

    rows = []
    for name in config.weights:
        for aware in (False, True):
            key, refined = ("rho_aware", "refined_aware") if aware else ("rho", "refined")
            mine = [r for r in records if r["weights"] == name]
            wrong = np.array([r[refined] != r["true"] for r in mine])
            rho = np.array([r[key] for r in mine])
            best = np.sort(rho, axis=1)
            p = np.clip(np.array([r["probs"] for r in mine]), 1e-9, 1.0)
            scores = {"1 - (best rho - second)": 1 - (best[:, -1] - best[:, -2]),
                      "entropy of the top-3 scores": -np.sum(p * np.log(p), axis=1),
                      "1 - best rho": 1 - best[:, -1]}
            if 0 < wrong.sum() < len(wrong):
                rows.append((name, "visibility-aware" if aware else "plain", len(mine), int(wrong.sum()),
                             *(f"{roc_auc_score(wrong, v):.3f}" for v in scores.values())))
    report.publish(report.section(
        "Which uncertainty predicts a wrong refined class (for the uncertainty-weighted view policy)", argv,
        ("weights", "rho", "segments", "wrong after GR", "AUROC: 1 - rho margin", "AUROC: entropy",
         "AUROC: 1 - best rho"), rows,
        intro="In-scene records of part 2 (all view counts); higher = the score ranks wrong segments above "
              "right ones better."), out)


if __name__ == "__main__":
    main()
