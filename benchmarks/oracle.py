"""The oracle NBV row of Table 1 (``protocol.oracle_rollouts``): a scene's runs tried together against one
run at a time, interleaved in one process.

    python benchmarks/oracle.py [--dataset synthetic] [--runs 10] [--moves 10] [--rounds 3] [--out BENCHMARKS.md]

The oracle fuses, segments, classifies and refines every candidate view of every run at every move and keeps
each run's best by true F1: runs x candidates moves per step. ``batched`` tries all ``--runs`` runs of the
scene in one vmapped call per step (what ``experiments/table1.py`` does by default); ``per run`` calls it
once per run (``oracle_runs_per_call=1``, the earlier host loop's shape). Both are compiled before timing;
the rounds alternate between them. Reported: median seconds per episode, the spread over rounds, and
whether the two reach the same final F1 per run.
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

from jaxcls import metrics, precision, report
from jaxcls.config import load_config
from jaxcls.episode import protocol, scoring, setup, sources
from jaxcls.world.dataset import DatasetConfig, build_dataset, scene_file
from jaxcls.world.objects import object_set_from_config


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="synthetic", help="a dataset config; its first scene is rendered")
    parser.add_argument("--data", default="data/oracle_bench", help="where that scene is rendered")
    parser.add_argument("--views", type=int, default=100, help="viewpoints of the scene")
    parser.add_argument("--classifier", default="", help="weights (\"\" = the shipped ones)")
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--moves", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    precision.full_float32_matmuls()
    dataset = load_config(DatasetConfig, args.dataset, ["num_scenes=1", f"out_dir={args.data}_{args.dataset}",
                                                        f"viewpoints.count={args.views}", "backend=mujoco"])
    build_dataset(dataset)
    object_set = object_set_from_config(dataset.objects)
    views = sources.dataset_source(scene_file(dataset.out_dir, 0), dataset.objects)
    truth = scoring.Truth.from_scene(views.scene, object_set)
    classifier = setup.load_classifier(args.classifier, object_set)
    base = setup.ActiveConfig(perception=setup.episode_perception(), refine=setup.episode_refine(),
                              nbv=setup.episode_nbv())
    episode = protocol.ROWS["oracle_gr"].episode(base, args.moves, classifier, object_set, views.intrinsics,
                                                 views.table_height, dataset.scene.split)
    starts = protocol.start_views(0, 0, args.runs, len(views.T_wc))
    keys = protocol.run_keys(0, 0, args.runs)
    classes = len(object_set.classes)

    def batched():
        return protocol.oracle_rollouts(episode, views.depth, views.T_wc, starts, keys, truth)

    def per_run():
        traces = [protocol.oracle_rollouts(episode, views.depth, views.T_wc, starts[r:r + 1], keys[r:r + 1], truth)
                  for r in range(args.runs)]
        return jax.tree.map(lambda *xs: np.concatenate(xs), *traces)

    def final_f1(traces) -> list[float]:
        out = []
        for r in range(args.runs):
            record = protocol.episode_record(jax.tree.map(lambda x, r=r: x[r], traces), truth)
            out.append(metrics.classification_scores(np.asarray(record["true"]), np.asarray(record["refined"][-1]),
                                                     classes).f1)
        return out

    ways = {"batched (all runs, one call per step)": batched, "per run (one call per run and step)": per_run}
    first, results, times = {}, {}, {name: [] for name in ways}
    for name, fn in ways.items():
        start = time.perf_counter()
        results[name] = fn()
        first[name] = time.perf_counter() - start
        print(f"{name}: first call {first[name]:.1f} s (compiles)", flush=True)
    for _ in range(args.rounds):
        for name, fn in ways.items():
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    f1 = {name: final_f1(traces) for name, traces in results.items()}
    reference = f1[next(iter(ways))]
    rows = []
    for name in ways:
        t = np.asarray(times[name])
        same = sum(abs(a - b) < 1e-9 for a, b in zip(f1[name], reference, strict=True))
        rows.append((name, report.device_name(), f"{first[name]:.1f}", f"{np.median(t) / args.runs:.2f}",
                     f"{t.min() / args.runs:.2f}-{t.max() / args.runs:.2f}", f"{np.mean(f1[name]):.3f}",
                     f"{same}/{args.runs}"))
        print(rows[-1], flush=True)
    report.publish(report.section(
        f"The oracle NBV row, {args.runs} runs of {args.moves} moves on one scene", argv,
        ("way", "device", "first call s (compile)", "median s per episode", "range over rounds",
         "mean final F1 (refined)", "runs with the batched way's final F1"), rows,
        intro=f"Scene 0 of `{args.dataset}` ({args.views} viewpoints, 640x480), OracleGR's settings, "
              f"{args.rounds} rounds alternating the two ways after one compiling call each."), args.out)


if __name__ == "__main__":
    main()
