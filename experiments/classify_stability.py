"""How stable is a segment's class? PointNet's answer under small changes of the same segment, for several
ways of feeding a segment to it, with their accuracy and CPU time.

    python experiments/classify_stability.py [--scenes 10] [--views 1 5] [--draws 4] [--out RESULTS.md]

Segments come from ``perception.observe`` (JAX segmentation) on held-out synthetic scenes (the
``synthetic`` world of ``jaxcls/configs/classify_in_scene.yaml``) along random hemisphere paths; each
segment's full point set is the surface points its labels give it. Ways to feed it (``METHODS``): the
evenly strided 1024, 512 or 256 points ``observe`` packs (deterministic), one random subset of 1024,
the mean probabilities of 4 random subsets, and all points (up to 4096, strided). Flip rates, over
``--draws`` draws per segment, of the predicted class against the method on the segment as it is:
``resampled`` (a random 90% of the segment's points), ``jitter`` (N(0, 1 mm) on every point), and
``reference`` (the segment the scikit-learn segmentation makes of the same surface, matched by its
majority object). Accuracy counts target segments with purity >= 0.8. Time: 5 segments, 2-core CPU.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxcls import metrics, perception, report
from jaxcls.config import load_config
from jaxcls.experiments.in_scene import InSceneConfig
from jaxcls.perception import pointnet, segment
from jaxcls.planning import nbv
from jaxcls.world import make_world
from jaxcls.world.dataset import scene_key, scene_seeds

PURITY = 0.8
JITTER = 0.001  # m


def _take(points: np.ndarray, size: int, rng: np.random.Generator | None) -> np.ndarray:
    """``size`` of ``points`` [n, 3]: evenly strided (``rng`` None) or a random subset; all when n <= size."""
    if len(points) <= size:
        return points
    if rng is None:
        return points[np.floor(np.arange(size) * len(points) / size).astype(int)]
    return points[np.sort(rng.choice(len(points), size, replace=False))]


def _classify(classifier, sets: list[np.ndarray], size: int, rng: np.random.Generator | None) -> np.ndarray:
    """[N, M] probabilities of point sets fed as ``_take(set, size, rng)``, padded to ``size``."""
    points = np.zeros((len(sets), size, 3), np.float32)
    mask = np.zeros((len(sets), size), bool)
    for n, s in enumerate(sets):
        chosen = _take(s, size, rng)
        points[n, :len(chosen)], mask[n, :len(chosen)] = chosen, True
    return np.asarray(pointnet.classify(classifier, points, mask))


def _method(size: int, subsets: int = 0) -> Callable:
    """A way to feed segments: strided ``size`` points (``subsets`` = 0) or the mean of ``subsets`` random
    subsets of ``size`` points."""
    def run(classifier, sets, rng):
        if subsets == 0:
            return _classify(classifier, sets, size, None)
        return np.mean([_classify(classifier, sets, size, rng) for _ in range(subsets)], axis=0)
    return run


METHODS = {"strided 1024 (observe)": _method(1024), "strided 512": _method(512), "strided 256": _method(256),
           "random 1024": _method(1024, 1), "mean of 4 random 1024": _method(1024, 4),
           "all points (<= 4096)": _method(4096)}


def segment_sets(segments, surface) -> list[np.ndarray]:
    """Each segment's full point set [n_i, 3] from the surface and the segmentation's labels."""
    labels, points, mask = (np.asarray(a) for a in (segments.labels, surface.points, surface.mask))
    return [points[(labels == n) & mask] for n in range(segments.mask.shape[0])]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--views", type=int, nargs="+", default=[1, 5])
    parser.add_argument("--draws", type=int, default=4, help="draws per segment for each flip rate")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", help="append the tables to this Markdown file")
    args = parser.parse_args(argv)
    world_config = load_config(InSceneConfig, "classify_in_scene").worlds["synthetic"]
    classifier = pointnet.load_classifier()
    rng = np.random.default_rng(args.seed)
    stats = {name: {"correct": [], "resampled": [], "jitter": [], "reference": []} for name in METHODS}
    seeds = scene_seeds(args.seed, args.scenes)
    for s in tqdm(range(args.scenes), desc="scenes"):
        world = make_world(world_config, seeds[s])
        owners = metrics.PointOwners(world.scene, world.models)
        label = np.array([classifier.classes.index(o.class_name) for o in world.scene.objects])
        spec = perception.Spec.create(intrinsics=world.intrinsics, table_height=world.table_height,
                                      classifier=classifier)
        path = nbv.random_walk(rng, world.viewpoints, max(args.views))
        depth, T_wc, _, _ = world.measure(scene_key(args.seed, s), path)
        state = perception.init_state(spec)
        for k, (d, T) in enumerate(zip(depth, T_wc, strict=True), start=1):
            state = perception.observe(spec, state, d, T)
            if k not in args.views:
                continue
            sets = segment_sets(state.segments, state.surface)
            truth = [metrics.segment_truth(owners(p, np.ones(len(p), bool))[None], np.ones((1, len(p)), bool))
                     for p in sets]
            scored = [n for n, t in enumerate(truth) if t.object[0] >= 0 and t.purity[0] >= PURITY]
            ref = segment.segment(spec, state.surface.points, state.surface.normals, state.surface.mask)
            ref_sets = segment_sets(ref, state.surface)
            ref_object = [metrics.segment_truth(owners(p, np.ones(len(p), bool))[None],
                                                np.ones((1, len(p)), bool)).object[0] for p in ref_sets]
            for name, method in METHODS.items():
                base = method(classifier, sets, rng).argmax(-1)
                stats[name]["correct"] += [base[n] == label[truth[n].object[0]] for n in scored]
                for _ in range(args.draws):
                    resampled = [p[rng.random(len(p)) < 0.9] for p in sets]
                    jittered = [p + rng.normal(0, JITTER, p.shape).astype(np.float32) for p in sets]
                    for key, changed in (("resampled", resampled), ("jitter", jittered)):
                        new = method(classifier, changed, rng).argmax(-1)
                        stats[name][key] += [new[n] != base[n] for n in scored]
                ref_pred = method(classifier, ref_sets, rng).argmax(-1)
                for n in scored:
                    twins = [r for r, o in enumerate(ref_object) if o == truth[n].object[0]]
                    if twins:
                        stats[name]["reference"].append(ref_pred[twins[0]] != base[n])
    sets5 = [np.asarray(np.random.default_rng(1).normal(size=(3000, 3)) * 0.03, np.float32) for _ in range(5)]
    rows = []
    for name, method in METHODS.items():
        seconds = report.timed(lambda m=method: jax.numpy.asarray(m(classifier, sets5, rng)), 10)[1]
        st = stats[name]
        rows.append((name, f"{np.mean(st['correct']):.3f}", len(st["correct"]), f"{np.mean(st['resampled']):.3f}",
                     f"{np.mean(st['jitter']):.3f}", f"{np.mean(st['reference']):.3f}", f"{seconds * 1e3:.0f}"))
    report.publish(report.section(
        f"Class stability of segments, {args.scenes} held-out synthetic scenes, views {args.views}", argv,
        ("fed as", "accuracy", "segments", "flips: resampled 90%", f"flips: jitter {JITTER * 1e3:.0f} mm",
         "flips: reference segmentation", "ms for 5 segments (CPU)"), rows,
        intro=f"Flip rates over {args.draws} draws per segment; accuracy and flips over target segments with "
              f"purity >= {PURITY}. Time: median of 10 calls, 5 segments of 3000 points."), args.out)


if __name__ == "__main__":
    main()
