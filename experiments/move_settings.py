"""Does the move's fast setting lose accuracy? Episodes with the episode's defaults (``setup.ActiveConfig()``:
PointNet on 256 points per segment, GR of 2 learned yaws pruned per class, 16 NBV candidates) against the
issue-20 settings (1024 points, ``RefineConfig()``: 8 even yaws, every model finished, 32 candidates) and
between them (3 learned yaws, every model finished), on the same held-out scenes, start views and keys.

    python experiments/move_settings.py --scenes 6 --moves 5 [--out RESULTS.md]
"""

from __future__ import annotations

import argparse

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxcls import metrics, report
from jaxcls.episode import active, runner, scoring, setup, sources
from jaxcls.perception.refine import RefineConfig
from jaxcls.perception.settings import PerceptionConfig
from jaxcls.planning.nbv import NBVConfig
from jaxcls.world import WorldConfig, make_world


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=6)
    parser.add_argument("--moves", type=int, default=5)
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    episode_config = active.EpisodeConfig(moves=args.moves)
    settings = {"the move's (ActiveConfig())": setup.ActiveConfig(episode=episode_config),
                "the move's, GR of 3 learned yaws, every model finished": setup.ActiveConfig(
                    episode=episode_config, refine=RefineConfig(yaw_source="learned", hypotheses=3)),
                "issue 20's (1024 points, RefineConfig(), 32 candidates)": setup.ActiveConfig(
                    episode=episode_config, perception=PerceptionConfig(), refine=RefineConfig(), nbv=NBVConfig())}
    per_scene = {name: {"prior": [], "refined": []} for name in settings}
    times = {name: [] for name in settings}
    object_set = make_world(WorldConfig(backend="mujoco"), seed=100).object_set
    for seed in tqdm(range(args.scenes), desc="scenes"):
        world = make_world(WorldConfig(backend="mujoco"), seed=100 + seed, object_set=object_set)
        truth = scoring.Truth.from_scene(world.scene, world.object_set)
        source = sources.Rendered(world, jax.random.PRNGKey(seed))
        start = int(np.random.default_rng(seed).integers(len(world.viewpoints)))
        for name, config in settings.items():
            episode = setup.make_episode(config, world.object_set, world.intrinsics, world.table_height)
            log = runner.run(episode, source, start, jax.random.PRNGKey(seed), truth)
            last = log.moves[-1]
            for label in ("prior", "refined"):
                per_scene[name][label].append((truth.label[truth.target],
                                               np.asarray(last["labels"][label])[truth.target]))
            times[name] += [sum(m["times_ms"].values()) for m in log.moves[1:]]
    M = len(world.object_set.classes)
    rows = []
    for name in settings:
        row = [name]
        for label in ("prior", "refined"):
            f1, lo, hi = metrics.scene_interval(per_scene[name][label], M)
            row.append(f"{f1:.3f} [{lo:.3f}, {hi:.3f}]")
        row.append(f"{np.median(times[name]):.0f}")
        rows.append(row)
    names = list(settings)
    differences = []
    for name in names[:-1]:
        d, lo, hi = metrics.paired_difference(per_scene[name]["refined"], per_scene[names[-1]]["refined"], M)
        differences.append(f"Paired difference of the refined F1, {name} minus issue 20's: {d:+.3f} "
                           f"[{lo:+.3f}, {hi:+.3f}].")
    report.publish(report.section(
        "The move's settings against issue 20's: F1 after the last move", argv,
        ("settings", f"F1 prior after {args.moves} moves", f"F1 refined after {args.moves} moves",
         "median ms per move (host, after the first)"), rows,
        intro=f"{args.scenes} held-out builtin scenes (seeds 100..), VisOcclHist, a random start view per scene, "
              "the same keys; 95% intervals resample scenes.",
        notes=differences),
        args.out)


if __name__ == "__main__":
    main()
