"""How cluttered are the scenes? Occlusion of each object by the others, over every viewpoint.

    python experiments/clutter.py --config configs/synthetic.yaml [key=value ...] [--out RESULTS.md]

For each scene of a dataset config (the world ``jaxcls dataset`` renders: ``make_world`` with the config's
world block and the scene's seed): render every viewpoint with all objects and with each object alone,
and report the visible fraction (seen / alone pixels) of (object, view) pairs where the object is in
view. The paper's premise is "severe inter-object occlusion" (Fig. 3): a scene set where every object is
always fully visible would make the choice of view pointless. ``--config`` takes a path or a shipped
config name (``synthetic``, ``real_like``).
"""

from __future__ import annotations

import argparse

import numpy as np
from tqdm.auto import tqdm

from jaxcls import report
from jaxcls.config import load_config
from jaxcls.world import make_world, scenes
from jaxcls.world.dataset import DatasetConfig, scene_seeds
from jaxcls.world.objects import object_set_from_config


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/synthetic.yaml")
    parser.add_argument("--out", help="append the table to this Markdown file")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_intermixed_args(argv)  # overrides may come before or after options
    cfg = load_config(DatasetConfig, args.config, args.overrides)
    object_set = object_set_from_config(cfg.objects)
    intrinsics = cfg.camera.intrinsics()
    rows, fractions = [], []
    for i, seed in enumerate(tqdm(scene_seeds(cfg.seed, cfg.num_scenes), desc="scenes")):
        world = make_world(cfg.world_config(), seed, object_set=object_set)
        scene = world.scene
        seen, alone = scenes.occlusion_counts(scene, world.models, world.intrinsics, world.viewpoints)
        in_view = alone > 0
        fraction = seen[in_view] / alone[in_view]
        fractions.append(fraction)
        worst = np.where(in_view, seen / np.maximum(alone, 1), 1.0).min(axis=0)  # [N] worst view per object
        rows.append((i, ", ".join(o.class_name for o in scene.objects), f"{fraction.mean():.2f}",
                     f"{np.mean(fraction < 0.75):.2f}", f"{np.mean(fraction < 0.5):.2f}",
                     f"{np.mean(worst < 0.5):.2f}"))
    every = np.concatenate(fractions)
    rows.append(("all", "", f"{every.mean():.2f}", f"{np.mean(every < 0.75):.2f}", f"{np.mean(every < 0.5):.2f}",
                 ""))
    table = report.section(
        f"Occlusion in `{args.config}` {' '.join(args.overrides)}".rstrip(), argv,
        ("scene", "objects", "mean visible fraction", "views < 75% visible", "views < 50% visible",
         "objects < 50% visible in some view"), rows,
        intro=f"{cfg.num_scenes} scenes x {cfg.viewpoints.count} views, {intrinsics.width}x{intrinsics.height}, "
              f"gaps {cfg.scene.min_gap * 1000:.0f}-{cfg.scene.max_gap * 1000:.0f} mm between footprints.")
    report.publish(table, args.out)


if __name__ == "__main__":
    main()
