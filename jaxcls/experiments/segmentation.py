"""Segmentation on fused scenes, both paths scored against the posed object surfaces
(``experiments/segmentation.py``; ``benchmarks/segment.py`` times the same chain on the same scenes).

Scenes: the builtin set, ``synthetic`` (footprint gaps 3 mm - 3 cm) and ``touching`` (1-5 mm), depth from the
``mujoco`` backend at five hemisphere views from low to high elevation (``VIEWS``), each frame through
``perception.observe`` (jitted: the JAX twin's move) into the default 0.6 m / 128^3 volume. A surface point's
ground truth is its nearest posed object surface; points more than 1 cm from every object are left out. After
1 and 5 views the reference path (scikit-learn DBSCAN + SciPy) segments the same surface; "agreement" is the
adjusted Rand index between the two paths' labels.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import metrics, perception
from jaxcls.geometry import CameraConfig
from jaxcls.perception import segment
from jaxcls.world import WorldConfig, make_world, scenes

VIEWS = (20, 35, 50, 65, 80)
KINDS = {"synthetic": scenes.SceneConfig(), "touching": scenes.SceneConfig(min_gap=0.001, max_gap=0.005)}
SCORED = (1, 5)  # views fused after which the segments are scored
PATHS = ("reference", "jax", "agreement")


def render_scene(kind: str, seed: int, scale: float):
    """(world, depth [V, H, W], T_wc [V, 4, 4], ground-truth function of points) of one scene at ``VIEWS``."""
    world = make_world(WorldConfig(scene=KINDS[kind], camera=CameraConfig.kinect_v1(scale), backend="mujoco"), seed)
    depth = world.render(list(VIEWS)).depth
    truth = metrics.PointOwners(world.scene, world.models)  # nearest posed object within 1 cm, else -1
    return world, np.asarray(depth), np.asarray(world.poses(list(VIEWS)), np.float32), truth


def fused(kind: str, seed: int, scale: float, settings: perception.PerceptionConfig, observe: Callable,
          scored: tuple[int, ...] = SCORED):
    """The scene's surfaces after each of ``scored`` views: (world, spec, truth, {views: state}); ``observe`` is
    ``perception.observe`` (jitted by the caller, so that one compiled move serves every scene)."""
    world, depth, Ts, truth = render_scene(kind, seed, scale)
    spec = perception.Spec.create(settings, world.intrinsics, world.table_height)
    state = perception.init_state(spec)
    states = {}
    for v in range(max(scored)):
        state = observe(spec, state, jnp.asarray(depth[v]), jnp.asarray(Ts[v]))
        if v + 1 in scored:
            states[v + 1] = state
    return world, spec, truth, states


def scores(spec: perception.Spec, truth, surface, labels) -> dict[str, float]:
    """ARI of the reference path and of the JAX twin's ``labels`` against the truth on ``surface``, and of the
    two against each other (points either labels)."""
    from sklearn.metrics import adjusted_rand_score

    p, n, m = np.asarray(surface.points), np.asarray(surface.normals), np.asarray(surface.mask)
    gt = truth(p, m)
    ref = np.asarray(segment.segment(spec, p, n, m).labels)
    twin = np.asarray(labels)
    sel, either = gt >= 0, (ref >= 0) | (twin >= 0)
    return {"reference": adjusted_rand_score(gt[sel], ref[sel]), "jax": adjusted_rand_score(gt[sel], twin[sel]),
            "agreement": adjusted_rand_score(ref[either], twin[either])}


def quality(seeds: int, scale: float, settings: perception.PerceptionConfig, observe: Callable | None = None
            ) -> dict[tuple[str, int, str], list[float]]:
    """(kind, views, path) -> ARI per scene (seeds 0..n-1 of each kind), on the CPU; progress on stderr."""
    observe = observe or jax.jit(perception.perceive)
    out: dict[tuple[str, int, str], list[float]] = {}
    with jax.default_device(jax.devices("cpu")[0]):
        for kind in KINDS:
            for seed in range(seeds):
                _, spec, truth, states = fused(kind, seed, scale, settings, observe)
                for views, state in states.items():
                    for path, value in scores(spec, truth, state.surface, state.segments.labels).items():
                        out.setdefault((kind, views, path), []).append(value)
                print(kind, seed, {k: round(x[-1], 3) for k, x in out.items() if k[0] == kind}, file=sys.stderr)
    return out


def quality_rows(ari: dict[tuple[str, int, str], list[float]]) -> list[tuple]:
    """The quality table's rows: scenes, views, path, mean ARI, min ARI, per scene."""
    return [(kind, views, what, f"{np.mean(v):.3f}", f"{np.min(v):.3f}", " ".join(f"{x:.2f}" for x in v))
            for (kind, views, what), v in sorted(ari.items(), key=lambda kv: (kv[0][0], kv[0][1]))]
