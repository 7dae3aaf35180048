"""Counting objects without a known N (issue 35): how often the estimated number of objects is right on fused
scenes, for both segmentation paths (``experiments/counting.py``).

The machinery is ``experiments.segmentation``'s: builtin scenes, depth from the ``mujoco`` backend at its five
hemisphere views from low to high elevation (``segmentation.VIEWS``), each frame through ``perception.observe``
(jitted: the JAX twin segments inside the move) into the default 0.6 m / 128^3 volume. Perception runs with
``shapes.num_objects = estimated`` and ``shapes.num_segments`` slots. After each of ``SCORED`` views the twin's
count is its live segments (a slot whose mask has points); the reference path (scikit-learn DBSCAN + SciPy)
segments the same surface. A scene's truth is the number of objects placed on it (an object not yet seen
counts as missed). Kinds: ``synthetic`` (5 objects, footprint gaps 3 mm - 3 cm), ``touching`` (5 objects,
1-5 mm), ``mixed`` (1 + seed % 8 objects, gaps as ``synthetic``: a scene set where N is not always 5).
"""

from __future__ import annotations

import sys
from collections.abc import Callable

import jax
import numpy as np

from jaxcls import perception
from jaxcls.experiments import segmentation
from jaxcls.perception import segment
from jaxcls.world import scenes

SCORED = (1, 3, 5)  # views fused after which the counts are taken
KINDS = ("synthetic", "touching", "mixed")
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


def live_count(seg: segment.Segments) -> int:
    """Segments with points: a slot is live when its mask has points."""
    return int(np.asarray(seg.mask).any(axis=-1).sum())


def counts(seeds: int, scale: float, settings: perception.PerceptionConfig, kinds: tuple[str, ...] = KINDS,
           observe: Callable | None = None, first_seed: int = 0) -> list[dict]:
    """One record a (kind, seed, views): ``objects`` on the table, each path's ``count`` and the ARI between
    the two paths' partitions (``agreement``, on the points both label) and the share of points both keep
    or both drop (``same_noise``). Seeds ``first_seed`` .. + n - 1 of each kind, on the CPU;
    progress on stderr."""
    from sklearn.metrics import adjusted_rand_score

    observe = observe or jax.jit(perception.perceive)
    out = []
    with jax.default_device(jax.devices("cpu")[0]):
        for kind in kinds:
            for seed in range(first_seed, first_seed + seeds):
                world, spec, _, states = segmentation.fused(_scene_kind(kind, seed), seed, scale, settings, observe,
                                                            SCORED)
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
