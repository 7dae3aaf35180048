"""Counting objects without a known N (issue 35): how often the estimated number of objects is right on fused
scenes, for both segmentation paths (``experiments/counting.py``).

The machinery is ``experiments.segmentation``'s: builtin scenes, depth from the ``mujoco`` backend at its five
hemisphere views from low to high elevation (``segmentation.VIEWS``), each frame through ``perception.observe``
(jitted: the JAX twin segments inside the move) into the default 0.6 m / 128^3 volume. Perception runs with
``shapes.num_objects = estimated`` and ``shapes.num_segments`` slots. After each of ``SCORED`` views the twin's
count is its live segments (a slot whose mask has points); the reference path (scikit-learn DBSCAN + SciPy)
segments the same surface. A scene's truth is the number of objects placed on it (an object not yet seen
counts as missed). Kinds: ``synthetic`` (5 objects, footprint gaps 3 mm - 3 cm), ``touching`` (5 objects,
1-5 mm), ``mixed`` (1 + seed % 8 objects, gaps as ``synthetic``: a scene set where N is not always 5), and
``real_like`` (not among the defaults, ``REAL_KINDS``): the ``real_like`` dataset config's world (3 targets + 2
clutter, gaps as ``synthetic``) seen through its sensor (Kinect-v1 depth noise, quantisation and dropout, one
hand-eye pose error per scene: the frames are fused at the poses the robot reports, which tracking corrects),
its noise drawn with ``real_like_key(seed)``. Every kind's truth is every object on the table: clutter is never
scored, but it is an object the segmentation should find, as the episode records count it (``objects``).

In the episode loop (``experiments/counting.py --episodes``: ``compare_runs``, ``episode_tables``): two Table 1 runs
alike but for ``perception.shapes.num_objects`` (and ``num_segments``), read from their stores and paired episode by
episode ((classifier, row, scene, run), ``paired_runs``): each run's count after moves 1, 3 and 10 (the records'
``segments`` against ``objects``: ``count_summary``) and F1 after T with N estimated minus F1 with N given, paired by
scene (``f1_comparison``: ``protocol.scene_labels`` per run, ``metrics.paired_differences``).

Why a run with N estimated miscounts (``--explain``: ``explain_episodes``, ``explain_surface``, ``explain_rows``):
its miscounted episodes replayed and each surface described against the posed objects. Choosing segmentation
settings apart from the evaluation's scenes (``--walks``: ``walk_counts``, ``walk_rows``): random walks of
RandomGR's kind on another dataset's scenes, counted under settings variants.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import metrics, perception
from jaxcls.episode import protocol
from jaxcls.experiments import segmentation
from jaxcls.experiments.table1.data import paired_runs, settings_differ
from jaxcls.perception import segment
from jaxcls.perception.settings import ESTIMATED_COUNT_FIELDS
from jaxcls.world import scenes

SCORED = (1, 3, 5)  # views fused after which the counts are taken
KINDS = ("synthetic", "touching", "mixed")  # the default kinds: ideal depth at the poses rendered
REAL_KINDS = ("real_like",)  # a dataset config's world and sensor (noise, hand-eye error): ``fused_real_like``
PATHS = ("reference", "jax")


def mixed_objects(seed: int) -> int:
    """The number of objects of the ``mixed`` kind's scene ``seed``: 1 to 8 in turn."""
    return 1 + seed % 8


def _scene_kind(kind: str, seed: int) -> str:
    """The name of ``segmentation.KINDS``'s scene config for this scene (``mixed`` adds one per count)."""
    if kind != "mixed":
        return kind
    name = f"mixed{mixed_objects(seed)}"
    segmentation.KINDS.setdefault(name, scenes.SceneConfig(num_objects=mixed_objects(seed)))
    return name


def real_like_key(seed: int) -> jax.Array:
    """The sensor-noise key of the ``real_like`` kind's scene ``seed`` (depth noise and the hand-eye error)."""
    return jax.random.fold_in(jax.random.PRNGKey(35), seed)


def fused_real_like(kind: str, seed: int, scale: float, settings: perception.PerceptionConfig, observe: Callable,
                    scored: tuple[int, ...] = SCORED):
    """``segmentation.fused`` for a ``REAL_KINDS`` kind: scene ``seed`` of the dataset config named ``kind``
    (its objects, scene with clutter, viewpoints and sensor; the Kinect v1 at ``scale``, the ``mujoco`` backend),
    measured at ``segmentation.VIEWS`` through its sensor model (``World.measure``, key ``real_like_key``) and
    fused at the poses it reports (hand-eye error included). (world, spec, None, {views: state})."""
    import dataclasses

    from jaxcls.config import load_config
    from jaxcls.geometry import CameraConfig
    from jaxcls.world import make_world
    from jaxcls.world.dataset import DatasetConfig

    config = load_config(DatasetConfig, kind).world_config()
    world = make_world(dataclasses.replace(config, camera=CameraConfig.kinect_v1(scale), backend="mujoco"), seed)
    depth, T_wc, _, _ = world.measure(real_like_key(seed), list(segmentation.VIEWS))
    spec = perception.Spec.create(settings, world.intrinsics, world.table_height)
    state = perception.init_state(spec)
    states = {}
    for v in range(max(scored)):
        state = observe(spec, state, jnp.asarray(depth[v], jnp.float32), jnp.asarray(T_wc[v], jnp.float32))
        if v + 1 in scored:
            states[v + 1] = state
    return world, spec, None, states


def live_count(seg: segment.Segments) -> int:
    """Segments with points: a slot is live when its mask has points."""
    return int(np.asarray(seg.mask).any(axis=-1).sum())


def counts(seeds: int, scale: float, settings: perception.PerceptionConfig, kinds: tuple[str, ...] = KINDS,
           observe: Callable | None = None, first_seed: int = 0) -> list[dict]:
    """One record a (kind, seed, views): ``objects`` on the table (targets and clutter), each path's ``count``
    and the ARI between
    the two paths' partitions (``agreement``, on the points both label) and the share of points both keep
    or both drop (``same_noise``). Seeds ``first_seed`` .. + n - 1 of each kind, on the CPU;
    progress on stderr."""
    from sklearn.metrics import adjusted_rand_score

    observe = observe or jax.jit(perception.perceive)
    out = []
    with jax.default_device(jax.devices("cpu")[0]):
        for kind in kinds:
            for seed in range(first_seed, first_seed + seeds):
                if kind in REAL_KINDS:
                    world, spec, _, states = fused_real_like(kind, seed, scale, settings, observe, SCORED)
                else:
                    world, spec, _, states = segmentation.fused(_scene_kind(kind, seed), seed, scale, settings,
                                                                observe, SCORED)
                for views, state in states.items():
                    p, n, m = (np.asarray(a) for a in (state.surface.points, state.surface.normals,
                                                       state.surface.mask))
                    ref = segment.segment(spec, p, n, m)
                    a, b = np.asarray(ref.labels), np.asarray(state.segments.labels)
                    both = (a >= 0) & (b >= 0)  # the ARI of one cluster against one plus noise is 0: points both keep
                    out.append({"kind": kind, "seed": seed, "views": views, "objects": len(world.scene.objects),
                                "reference": live_count(ref), "jax": live_count(state.segments),
                                "agreement": float(adjusted_rand_score(a[both], b[both])) if both.any() else 1.0,
                                "same_noise": float(np.mean((a >= 0) == (b >= 0)))})
                print(kind, seed, [(r["views"], r["objects"], r["reference"], r["jax"]) for r in out[-len(states):]],
                      file=sys.stderr, flush=True)
    return out


def count_rows(records: list[dict]) -> list[tuple]:
    """The table's rows, a (kind, views, path): scenes, share right, mean |count - objects|, mean count -
    objects (signed: < 0 = objects merged or missed), the errors' spread; for ``agreement``, the share of
    scenes where the two paths' counts are equal, the mean ARI between their partitions (points both label)
    and the mean share of points both keep or both drop."""
    rows = []
    for kind in dict.fromkeys(r["kind"] for r in records):
        for views in sorted({r["views"] for r in records}):
            sel = [r for r in records if r["kind"] == kind and r["views"] == views]
            for path in PATHS:
                err = np.array([r[path] - r["objects"] for r in sel])
                spread = " ".join(f"{e:+d}:{int(np.sum(err == e))}" for e in np.unique(err))
                rows.append((kind, views, path, len(sel), f"{np.mean(err == 0):.3f}", f"{np.mean(np.abs(err)):.3f}",
                             f"{np.mean(err):+.3f}", spread))
            same = np.mean([r["reference"] == r["jax"] for r in sel])
            ari, noise = np.mean([r["agreement"] for r in sel]), np.mean([r["same_noise"] for r in sel])
            rows.append((kind, views, "agreement", len(sel), f"{same:.3f}", "", "",
                         f"mean ARI {ari:.3f}, same noise {noise:.3f}"))
    return rows


# --- Counting in the episode loop: two Table 1 runs, N given against N estimated --------------------------------

EPISODE_MOVES = (1, 3, 10)  # moves after which an episode's count is read (past an episode's last move: its last)
# The settings two compared runs may differ in: how the objects are counted and the slots they may fill.
COUNT_SETTINGS = ("num_objects", "num_segments")


def count_errors(records: Sequence[dict[str, Any]], move: int) -> np.ndarray:
    """[E] i64: each episode's live segments after ``move`` (1-based; an episode of fewer moves, its last)
    minus its scene's objects (``protocol.episode_records``' ``segments`` and ``objects``): < 0 objects merged
    or missed, > 0 objects split or phantoms."""
    return np.array([r["segments"][min(move, len(r["segments"])) - 1] - r["objects"] for r in records], np.int64)


def _share_interval(right: np.ndarray, total: np.ndarray, resamples: int, seed: int = 0
                    ) -> tuple[float, float, float]:
    """(share, low, high): sum(right) / sum(total) over scenes ([S] each: a scene's episodes right and in all)
    and its 95% percentile bootstrap interval, resampling whole scenes (``metrics.scene_interval``'s rule)."""
    from scipy.stats import bootstrap

    share = float(right.sum() / total.sum())
    if len(right) < 2:
        return share, share, share
    result = bootstrap((np.arange(len(right)),), lambda picks, axis: right[picks].sum(-1) / total[picks].sum(-1),
                       vectorized=True, axis=-1, confidence_level=0.95, n_resamples=resamples, method="percentile",
                       rng=np.random.default_rng(seed))
    return share, float(result.confidence_interval.low), float(result.confidence_interval.high)


def count_summary(records: Sequence[dict[str, Any]], move: int, resamples: int = 2000) -> dict[str, Any]:
    """One row's counts after ``move``: ``episodes`` right (share, with ``low``/``high`` its scene-bootstrap
    interval), ``scenes`` right in every run (share of scenes whose every episode counted its objects),
    ``abs`` the mean |count - objects|, ``mean`` the signed mean, ``spread`` {error: episodes}, ``n`` episodes
    and ``scene_count`` scenes."""
    error = count_errors(records, move)
    scene = np.array([int(r["scene"]) for r in records], np.int64)
    scenes, at = np.unique(scene, return_inverse=True)
    right = np.bincount(at, weights=error == 0, minlength=len(scenes))
    total = np.bincount(at, minlength=len(scenes)).astype(np.float64)
    share, low, high = _share_interval(right, total, resamples)
    values, counts = np.unique(error, return_counts=True)
    return {"episodes": share, "low": low, "high": high, "scenes": float(np.mean(right == total)),
            "abs": float(np.abs(error).mean()), "mean": float(error.mean()),
            "spread": dict(zip(values.tolist(), counts.tolist(), strict=True)), "n": len(records),
            "scene_count": len(scenes)}


def f1_comparison(known: Sequence[dict[str, Any]], estimated: Sequence[dict[str, Any]], classes: int,
                  resamples: int = 2000) -> dict[str, Any]:
    """F1 of one row's paired episodes (``paired_runs``) after its last move (T): each run's F1 (``given``,
    ``estimated``) and with every phantom segment a false positive of its class (``given_phantoms``,
    ``estimated_phantoms``: ``protocol.scene_labels(..., phantoms=True)``), and three differences paired by scene
    with their 95% scene-bootstrap intervals, (estimate, low, high) each, from one bootstrap
    (``metrics.paired_differences``): ``difference`` estimated with phantoms counted - given without (the
    phantoms exist where N is estimated; with N given every slot is a segment, the paper's F1),
    ``difference_phantoms`` both with phantoms counted, ``difference_plain`` neither."""
    T = max(len(r["refined"]) for r in [*known, *estimated])
    sets = {"given": protocol.scene_labels(known).at(T),
            "given_phantoms": protocol.scene_labels(known, phantoms=True).at(T),
            "estimated": protocol.scene_labels(estimated).at(T),
            "estimated_phantoms": protocol.scene_labels(estimated, phantoms=True).at(T)}
    if len(sets["given"]) != len(sets["estimated"]):
        raise ValueError(f"f1_comparison: {len(sets['given'])} and {len(sets['estimated'])} scenes; pair the runs "
                         "first (paired_runs)")
    out: dict[str, Any] = {k: metrics.classification_scores(np.concatenate([t for t, _ in v]),
                                                            np.concatenate([p for _, p in v]), classes).f1
                           for k, v in sets.items()}
    found = metrics.paired_differences(
        [(sets["estimated_phantoms"], sets["given"]), (sets["estimated_phantoms"], sets["given_phantoms"]),
         (sets["estimated"], sets["given"])], classes, resamples=resamples)
    out.update(zip(("difference", "difference_phantoms", "difference_plain"), found, strict=True))
    out["moves"] = T
    return out


def episode_tables(known: Sequence[dict[str, Any]], estimated: Sequence[dict[str, Any]], classes: int,
                   moves: Sequence[int] = EPISODE_MOVES, resamples: int = 2000, labels: dict[str, str] | None = None
                   ) -> tuple[list[tuple], list[tuple]]:
    """The comparison's two tables from the stores of two Table 1 runs alike but for how N is set, their
    episodes paired (``paired_runs``): (count rows, F1 rows). A count row a (classifier, row, N, move):
    episodes, episodes right [95% scene-bootstrap interval], scenes right in every run, mean |error|, mean
    error, the errors' spread; ``moves`` past a row's last move read its last (PointNetSingle: its one move).
    An F1 row a (classifier, row): scenes, episodes, T, each run's F1 plain and with phantoms counted, and the
    three paired differences (``f1_comparison``). ``labels``: row name -> its printed label."""
    labels = labels or {}
    count_rows, f1_rows = [], []
    for (classifier, row), (k, e) in paired_runs(known, estimated).items():
        T = max(len(r["segments"]) for r in [*k, *e])
        label = labels.get(row, row)
        for name, records in (("given", k), ("estimated", e)):
            for move in dict.fromkeys(min(m, T) for m in moves):
                s = count_summary(records, move, resamples)
                spread = " ".join(f"{v:+d}:{c}" for v, c in s["spread"].items())
                count_rows.append((classifier, label, name, move, s["n"],
                                   f"{s['episodes']:.3f} [{s['low']:.3f}, {s['high']:.3f}]", f"{s['scenes']:.3f}",
                                   f"{s['abs']:.3f}", f"{s['mean']:+.3f}", spread))
        f = f1_comparison(k, e, classes, resamples)
        f1_rows.append((classifier, label, len({r["scene"] for r in k}), len(k), f["moves"], f"{f['given']:.3f}",
                        f"{f['given_phantoms']:.3f}", f"{f['estimated']:.3f}", f"{f['estimated_phantoms']:.3f}",
                        *(metrics.format_difference(*f[d])
                          for d in ("difference", "difference_phantoms", "difference_plain"))))
    return count_rows, f1_rows


COUNT_HEADER = ("classifier", "method", "N", "after move", "episodes", "N right: episodes [95% CI, scenes]",
                "scenes right in every run", "mean abs error", "mean error", "errors (count - objects: episodes)")
F1_HEADER = ("classifier", "method", "scenes", "episodes", "T", "F1, N given", "F1, N given, phantoms counted",
             "F1, N estimated", "F1, N estimated, phantoms counted",
             "estimated (phantoms counted) - given [95% CI]", "both with phantoms counted", "neither")


def run_settings_differ(known: Any, estimated: Any) -> list[str]:
    """The keys (dotted) in which two ``Table1Config``s' results-defining settings differ, besides how N is set
    (``perception.shapes``' ``COUNT_SETTINGS``) and the segmentation settings only an estimated count reads
    (``settings.ESTIMATED_COUNT_FIELDS``): [] where the runs are comparable."""
    skip = ({f"perception.shapes.{k}" for k in COUNT_SETTINGS}
            | {f"perception.segmentation.{k}" for k in ESTIMATED_COUNT_FIELDS})
    return [k for k in settings_differ(known, estimated) if k not in skip]


def compare_runs(known_dir: str | Path, estimated_dir: str | Path, moves: Sequence[int] = EPISODE_MOVES,
                 resamples: int = 2000, classes: int | None = None
                 ) -> tuple[list[tuple], list[tuple], dict[str, Any]]:
    """``episode_tables`` of two Table 1 output folders (``experiments/table1.py``'s ``out_dir``: its
    ``config.yaml`` and every process's episode store), the first with N given, the second with N estimated;
    their configs must agree but for ``COUNT_SETTINGS`` (ValueError naming the keys otherwise). ``classes``:
    the classifier's class count (default: the dataset's object set's). Also returns facts for the intro:
    ``dataset``, ``slots`` (the estimated run's num_segments), ``runs``, ``moves``."""
    from jaxcls.config import load_config
    from jaxcls.experiments.table1 import data
    from jaxcls.experiments.table1.config import Table1Config
    from jaxcls.perception.settings import ObjectCount

    folders = Path(known_dir), Path(estimated_dir)
    configs = [load_config(Table1Config, f / "config.yaml") for f in folders]
    for folder, config, want in zip(folders, configs, (ObjectCount.known, ObjectCount.estimated), strict=True):
        if config.perception.shapes.num_objects != want:
            raise ValueError(f"{folder}: perception.shapes.num_objects is {config.perception.shapes.num_objects}, "
                             f"expected {want} (give the run with N given first, then the one with N estimated)")
    differ = run_settings_differ(*configs)
    if differ:
        raise ValueError(f"{folders[0]} and {folders[1]}: the runs differ in {differ}, not only in how N is set")
    known, estimated = (data.stored_records(c, f / "episodes.jsonl") for c, f in zip(configs, folders, strict=True))
    if classes is None:
        from jaxcls.world.objects import object_set_from_config

        classes = len(object_set_from_config(data.dataset_config(configs[0]).objects).classes)
    count_rows, f1_rows = episode_tables(known, estimated, classes, moves, resamples,
                                         {name: row.label for name, row in protocol.ROWS.items()})
    return count_rows, f1_rows, {"dataset": configs[0].dataset, "slots": configs[1].perception.shapes.num_segments,
                                 "given_slots": configs[0].perception.shapes.num_segments,
                                 "runs": configs[0].runs, "moves": configs[0].moves}


# --- Why a count is wrong: each segment of a fused surface described against the scene's objects ---------------

MISSED_POINTS = 20  # an object with fewer surface points than this is unseen


def explain_surface(spec: perception.Spec, points: np.ndarray, normals: np.ndarray, mask: np.ndarray,
                    owners: np.ndarray, objects: int) -> dict[str, list[dict[str, Any]]]:
    """The reference path's estimated-count segmentation of a surface described against the truth:
    ``segments``, one dict a live segment (``segment.reference._watershed_reference``'s groups after the merge,
    fragments under ``min_object_area`` left out as the path drops them), and ``objects``, one a scene object.

    points, normals: [P, 3] (m, unit); mask: [P] bool; owners: [P] i64 each point's object (``metrics.PointOwners``:
    the nearest posed object within 1 cm, -1 = none); objects: the scene's object count. A segment's ``object`` is
    its points' majority owner (-1 when most points belong to none), ``purity`` that owner's share, ``unowned`` the
    share owned by none; ``area`` its footprint (closed, filled cells), m^2; ``height`` its highest point above the
    table, m; ``points``; ``basins`` merged into it; ``persistence`` the cost of its cheapest merge
    (``_merge_costs``: the relative persistence (peak - saddle) / peak, scaled where flush; >= 1: apart on the
    table; inf: the highest basin); ``kind``: ``object`` (the largest segment of its object), ``second`` (another
    segment of an object that has a larger one), ``ghost`` (mostly no object's points). An object's ``points`` on
    the surface and ``fate``: ``found`` (the segment holding most of its points is its own), ``merged`` (that
    segment is another object's; ``into`` names it), ``dropped`` (seen, but in no live segment: noise or a
    fragment) or ``unseen`` (fewer than ``MISSED_POINTS`` points).
    """
    from jaxcls.perception.foreground import foreground_mask
    from jaxcls.perception.segment import common, reference

    fg = np.asarray(foreground_mask(spec, jnp.asarray(points), jnp.asarray(mask)))
    x, n, own = np.asarray(points, np.float64)[fg], np.asarray(normals, np.float64)[fg], np.asarray(owners)[fg]
    parts = reference._watershed_reference(spec, x, n)
    segments: list[dict[str, Any]] = []
    group = np.full(len(x), -1, np.int64)
    if parts is not None:
        merged = parts.merged
        cost, _ = common._merge_costs(np, merged, parts.peak, common._count_rule(spec))
        live = merged.alive & ~common._too_small(merged, spec)
        group[parts.good] = np.where(live[parts.group], parts.group, -1)
        for g in np.flatnonzero(live):
            sel = group == g
            o = own[sel]
            found, votes = np.unique(o[o >= 0], return_counts=True)
            best = int(found[np.argmax(votes)]) if len(found) else -1
            unowned = float(np.mean(o < 0))
            segments.append({"group": int(g), "object": best if unowned < 0.5 else -1,
                             "purity": float(np.mean(o == best)) if best >= 0 else 0.0, "unowned": unowned,
                             "area": float(merged.size[g] * spec.segmentation.footprint_cell ** 2),
                             "height": float(x[sel, 2].max() - spec.table_height), "points": int(sel.sum()),
                             "basins": int(np.sum(merged.group == g)), "persistence": float(cost[g]),
                             "centre": x[sel].mean(0).round(3).tolist()})
    for seg in segments:
        rivals = [t["points"] for t in segments if t is not seg and t["object"] == seg["object"]]
        seg["kind"] = "ghost" if seg["object"] < 0 else "second" if rivals and max(rivals) > seg["points"] else "object"
    owner_of = {seg["group"]: seg["object"] for seg in segments}
    fates = []
    for k in range(objects):
        mine = own == k
        held = group[mine & (group >= 0)]
        if mine.sum() < MISSED_POINTS:
            fate, into = "unseen", -1
        elif not len(held):
            fate, into = "dropped", -1
        else:
            into = owner_of[int(np.bincount(held).argmax())]
            fate = "found" if into == k else "merged"
        fates.append({"object": k, "points": int(mine.sum()), "fate": fate, "into": into if fate == "merged" else -1})
    return {"segments": segments, "objects": fates}


def explain_segments(spec: perception.Spec, points: np.ndarray, normals: np.ndarray, mask: np.ndarray,
                     owners: np.ndarray) -> list[dict[str, Any]]:
    """``explain_surface``'s ``segments``: each live segment of the surface described against the truth."""
    return explain_surface(spec, points, normals, mask, owners, 0)["segments"]


def explain_episodes(run_dir: str | Path, moves: Sequence[int] = (3, 10), limit: int = 0,
                     twin: bool = True, overrides: Sequence[str] = ()) -> list[dict[str, Any]]:
    """The miscounted episodes of a Table 1 run with N estimated (``run_dir``: its ``config.yaml`` and
    episode store), replayed: each episode's recorded views fused again through the run's perception (tracking
    included) and, after each of ``moves`` at which its live segments were not its objects, the surface
    described (``explain_surface``). One record a (episode, move): its keys, ``recorded`` the store's count,
    ``twin`` the JAX twin's count on the replayed surface (``twin``), ``objects`` the scene's count (targets and
    clutter), ``segments`` and ``fates`` (``explain_surface``'s ``segments`` and ``objects``, each with its
    object's instance ``name`` and ``target``: False for clutter, None for a ghost; a merged object's fate also
    ``into_target``, whether the object it was merged into is a target).
    ``limit``: at most this many episodes (0 = all). ``overrides``: dotted settings laid over the run's config
    for the replay (a run stored before a segmentation setting existed: its value then, e.g.
    ``perception.segmentation.flush_persistence=0.15``). The replay counts the segmentation's segments: where
    the run's GR explained a part as a larger segment's object (``segmentation.explained_share``, on by default
    since dbd802e), ``recorded`` is below what the surface shows, so recorded and twin differ there by design.
    Progress on stderr."""
    from jaxcls.config import load_config
    from jaxcls.experiments.table1 import data
    from jaxcls.experiments.table1.config import Table1Config
    from jaxcls.perception import observation
    from jaxcls.world.scenes import scene_models

    folder = Path(run_dir)
    config = load_config(Table1Config, folder / "config.yaml", overrides)
    records = data.stored_records(config, folder / "episodes.jsonl")
    wrong = [r for r in records if any(count_errors([r], m)[0] != 0 for m in moves)]
    wrong = wrong[:limit] if limit else wrong
    _, scene_set = data.open_scenes(config)
    reconstruct = jax.jit(observation.reconstruct)
    out: list[dict[str, Any]] = []
    cache: dict[int, Any] = {}
    for r in wrong:
        i = int(r["scene"])
        if i not in cache:
            cache.clear()
            frames = scene_set.load([i])[0]
            cache[i] = frames, metrics.PointOwners(frames.scene, scene_models(frames.scene))
        frames, owners = cache[i]
        names = [o.name for o in frames.scene.objects]
        targets = [bool(o.target) for o in frames.scene.objects]
        spec = perception.Spec.create(config.perception, frames.intrinsics, frames.table_height)
        state = perception.init_state(spec)
        for t, view in enumerate(r["path"][:max(moves)], start=1):
            depth, T_wc = frames.frame(view)
            state = reconstruct(spec, state, jnp.asarray(depth, jnp.float32), jnp.asarray(T_wc, jnp.float32))
            if t not in moves or count_errors([r], t)[0] == 0:
                continue
            s = state.surface
            p, nrm, m = np.asarray(s.points), np.asarray(s.normals), np.asarray(s.mask)
            described = explain_surface(spec, p, nrm, m, owners(p, m), len(names))
            for d in [*described["segments"], *described["objects"]]:
                d["name"] = names[d["object"]] if d["object"] >= 0 else ""
                d["target"] = targets[d["object"]] if d["object"] >= 0 else None
            for d in described["objects"]:
                if d["fate"] == "merged":
                    d["into_target"] = targets[d["into"]] if d["into"] >= 0 else None
            count = live_count(segment.segment_jax(spec, p, nrm, m)) if twin else -1
            out.append({**{k: r[k] for k in ("classifier", "row", "scene", "run")}, "move": t,
                        "recorded": r["segments"][t - 1], "twin": count, "objects": r["objects"],
                        "segments": described["segments"], "fates": described["objects"]})
            print(r["row"], i, r["run"], t, out[-1]["recorded"], count, len(out[-1]["segments"]),
                  [d["kind"] for d in out[-1]["segments"] if d["kind"] != "object"],
                  [d["fate"] for d in out[-1]["fates"] if d["fate"] != "found"], file=sys.stderr, flush=True)
    return out


EXPLAIN_HEADER = ("after move", "segment or object", "touching or apart", "class", "count",
                  "median persistence", "median area (cm^2)", "median height (cm)")


def explain_rows(explained: Sequence[dict[str, Any]]) -> list[tuple]:
    """``explain_episodes``' miscounts summed up, one row a (move, what, touching or apart, class), most first
    within a move: the segments that are not their object's largest (``second``, ``ghost``: over-counts), with
    the median cost of their cheapest merge (< 1: touching another segment; >= 1: apart on the table), area and
    height; and the objects without a segment of their own (``missed: merged`` into another's, ``missed:
    dropped``, ``missed: unseen``: under-counts). Where the records say which objects are clutter (``target``
    False: ``explain_episodes``), a clutter object's class reads ``<class> (clutter)``, and an object merged
    into a clutter object's segment ``missed: merged into clutter`` (into a target's: ``missed: merged``)."""
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for e in explained:
        for s in e["segments"]:
            if s["kind"] == "object":
                continue
            where = "touching" if s["persistence"] < 1.0 else "apart"
            groups.setdefault((e["move"], s["kind"], where, _class(s)), []).append(s)
        for o in e.get("fates", []):
            if o["fate"] != "found":
                fate = "merged into clutter" if o["fate"] == "merged" and o.get("into_target") is False else o["fate"]
                groups.setdefault((e["move"], f"missed: {fate}", "", _class(o)), []).append(o)
    rows = []
    for key, items in sorted(groups.items(), key=lambda kv: (kv[0][0], -len(kv[1]), kv[0][1:])):
        if "persistence" in items[0]:
            rows.append((*key, len(items), f"{np.median([s['persistence'] for s in items]):.2f}",
                         f"{np.median([s['area'] for s in items]) * 1e4:.0f}",
                         f"{np.median([s['height'] for s in items]) * 100:.1f}"))
        else:
            rows.append((*key, len(items), "", "", ""))
    return rows


def _class(item: dict[str, Any]) -> str:
    """The class of a described segment's or object's instance (its name's prefix), ``none`` without one;
    ``<class> (clutter)`` where the item is a clutter object's (``target`` False)."""
    name = item.get("name", "").split("_")[0] or "none"
    return f"{name} (clutter)" if item.get("target") is False else name


# --- Tuning on random walks: Table 1's perception along RandomGR-like paths, counted with settings variants -----

WALK_MOVES = (1, 3, 10)  # moves after which a walk's surface is counted


def walk_counts(config_path: str | Path, overrides: Sequence[str], runs: int,
                variants: dict[str, dict[str, float]], moves: Sequence[int] = WALK_MOVES, seed: int = 7
                ) -> list[dict[str, Any]]:
    """Counts of random walks, for choosing segmentation settings on scenes apart from the evaluation's.

    The Table 1 config at ``config_path`` with ``overrides`` (its dataset, e.g. another seed) gives the scenes and
    the perception; each scene gets ``runs`` walks of max(``moves``) views, each view drawn at random among the
    unvisited ones within 0.5 m of the last (RandomGR's candidates; any unvisited one where none is near), from a
    random start (``numpy`` seeded by ``seed``, the scene and the run), fused through the perception (tracking
    included). After each of ``moves`` the reference path counts the surface under every variant (name ->
    ``perception.segmentation`` fields laid over the config's). One record a (scene, run, move, variant):
    ``objects``, ``count``, and against the posed objects (``object_coverage``) ``seen`` (objects with at least
    ``MISSED_POINTS`` surface points), ``found`` (of them, those with a segment of their own) and ``whole`` (each
    found object's share of its points in its segment, summed over them). Progress on stderr."""
    import dataclasses

    from jaxcls.config import load_config
    from jaxcls.experiments.table1 import data
    from jaxcls.experiments.table1.config import Table1Config
    from jaxcls.perception import observation
    from jaxcls.perception.foreground import foreground_mask
    from jaxcls.perception.segment import reference
    from jaxcls.world.scenes import scene_models

    config = load_config(Table1Config, config_path, overrides)
    _, scene_set = data.open_scenes(config)
    reconstruct = jax.jit(observation.reconstruct)
    out: list[dict[str, Any]] = []
    for i in range(scene_set.count):
        frames = scene_set.load([i])[0]
        owners = metrics.PointOwners(frames.scene, scene_models(frames.scene))
        spec = perception.Spec.create(config.perception, frames.intrinsics, frames.table_height)
        specs = {name: spec.replace(config=dataclasses.replace(
            config.perception, segmentation=dataclasses.replace(config.perception.segmentation, **fields)))
            for name, fields in variants.items()}
        where = frames.T_wc[:, :3, 3]
        for run in range(runs):
            rng = np.random.default_rng([seed, i, run])
            view, visited = int(rng.integers(len(where))), []
            state = perception.init_state(spec)
            for t in range(1, max(moves) + 1):
                visited.append(view)
                depth, T_wc = frames.frame(view)
                state = reconstruct(spec, state, jnp.asarray(depth, jnp.float32), jnp.asarray(T_wc, jnp.float32))
                if t in moves:
                    s = state.surface
                    p, n, m = np.asarray(s.points), np.asarray(s.normals), np.asarray(s.mask)
                    fg = np.asarray(foreground_mask(spec, jnp.asarray(p), jnp.asarray(m)))
                    own = owners(p, m)[fg]
                    objects = len(frames.scene.objects)
                    for name, sp in specs.items():
                        labels = reference.cluster_reference(sp, p[fg].astype(np.float64), n[fg].astype(np.float64))
                        out.append({"scene": i, "run": run, "move": t, "variant": name, "objects": objects,
                                    "count": len(np.unique(labels[labels >= 0])),
                                    **object_coverage(labels, own, objects)})
                free = [v for v in range(len(where)) if v not in visited]
                near = [v for v in free if np.linalg.norm(where[v] - where[view]) < 0.5] or free
                view = int(rng.choice(near))
        print("walks: scene", i, file=sys.stderr, flush=True)
    return out


def object_coverage(labels: np.ndarray, owners: np.ndarray, objects: int) -> dict[str, float]:
    """How a partition holds the scene's objects: ``seen`` objects (at least ``MISSED_POINTS`` points), ``found``
    (of them, those whose points lie mostly in a segment whose points are mostly theirs) and ``whole`` (each found
    object's share of its points in that segment, summed over the found ones).

    labels: [M] i64 each point's segment, -1 = none; owners: [M] i64 each point's object, -1 = none."""
    seen = found = 0
    whole = 0.0
    for k in range(objects):
        mine = owners == k
        if mine.sum() < MISSED_POINTS:
            continue
        seen += 1
        held = labels[mine & (labels >= 0)]
        if not len(held):
            continue
        g = int(np.bincount(held).argmax())
        members = owners[labels == g]
        if np.bincount(members[members >= 0], minlength=objects).argmax() == k and np.mean(members >= 0) >= 0.5:
            found += 1
            whole += float(np.mean(labels[mine] == g))
    return {"seen": seen, "found": found, "whole": whole}


WALK_HEADER = ("variant", "after move", "walks", "N right", "over", "under", "objects found",
               "found objects' points in their segment")


def walk_rows(records: Sequence[dict[str, Any]]) -> list[tuple]:
    """``walk_counts``' table (``WALK_HEADER``): one row a (variant, move): walks, share right, over- and
    under-counted walks, the share of seen objects found and the mean share of a found object's points in its
    segment (``object_coverage``)."""
    rows = []
    for name in dict.fromkeys(r["variant"] for r in records):
        for move in sorted({r["move"] for r in records}):
            mine = [r for r in records if r["variant"] == name and r["move"] == move]
            err = np.array([r["count"] - r["objects"] for r in mine])
            seen, found = sum(r["seen"] for r in mine), sum(r["found"] for r in mine)
            rows.append((name, move, len(err), f"{np.mean(err == 0):.3f}", int(np.sum(err > 0)), int(np.sum(err < 0)),
                         f"{found / max(seen, 1):.3f}", f"{sum(r['whole'] for r in mine) / max(found, 1):.3f}"))
    return rows
