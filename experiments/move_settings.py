"""What the move's GR settings cost in accuracy: episodes with GR variants on the same held-out scenes, start
views and keys (PointNet on 256 points and 16 NBV candidates in every variant, so that only GR differs),
scored after the first move (one view: where GR matters most) and after the last.

    python experiments/move_settings.py --scenes 30 --moves 5 [--out RESULTS.md]

Variants: the episode's default GR (``setup.episode_refine()``) and the levers it pulls one by one:
``hypotheses`` (learned yaws), ``prune_per`` (finish the best (model, yaw) per class or per model),
``prune_neighbours`` (the pruning rho's neighbours); and issue 20's ``RefineConfig()`` (8 even yaws).
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxcls import metrics, report
from jaxcls.episode import active, runner, scoring, setup, sources
from jaxcls.perception.refine import RefineConfig
from jaxcls.world import WorldConfig, make_world


def variants(which: str = "levers") -> dict[str, RefineConfig]:
    base = setup.episode_refine()
    if which == "pruning":  # under Eq. 3, whose decisions show what the pruning changes
        eq3 = dataclasses.replace(base, decision="rho")
        return {"default, Eq. 3": eq3, "prune on 128 points": dataclasses.replace(eq3, prune_points=128),
                "prune after 2 iterations": dataclasses.replace(eq3, prune_after=2),
                "both": dataclasses.replace(eq3, prune_points=128, prune_after=2)}
    if which == "models":  # under Eq. 3
        eq3 = dataclasses.replace(base, decision="rho")
        return {"default, Eq. 3": eq3, "2 models per class (nearest height)": dataclasses.replace(
            eq3, models_per_class=2), "1 model per class": dataclasses.replace(eq3, models_per_class=1)}
    if which == "decision":
        return {"Eq. 3 (argmax rho)": dataclasses.replace(base, decision="rho"),
                "p x rho": dataclasses.replace(base, decision="product"),
                "RefineConfig() with p x rho": RefineConfig(decision="product")}
    base = dataclasses.replace(base, decision="rho")  # the levers under Eq. 3, whose decisions show them
    return {
        f"default: {base.hypotheses} learned yaws, per class, {base.prune_neighbours} neighbours": base,
        "3 learned yaws": dataclasses.replace(base, hypotheses=3),
        "per model": dataclasses.replace(base, prune_per="model"),
        "all neighbours": dataclasses.replace(base, prune_neighbours=None),
        "3 learned yaws, per model, all neighbours": dataclasses.replace(base, hypotheses=3, prune_per="model",
                                                                          prune_neighbours=None),
        "RefineConfig(): 8 even yaws, per model": RefineConfig(),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=30)
    parser.add_argument("--moves", type=int, default=5)
    parser.add_argument("--variants", choices=("levers", "decision", "pruning", "models"), default="levers",
                        help="levers: the pruning settings one by one; decision: Eq. 3 against p x rho; "
                             "pruning: cheaper pruning; models: fewer models per class")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    episode_config = active.EpisodeConfig(moves=args.moves)
    settings = {name: setup.ActiveConfig(episode=episode_config, refine=refine)
                for name, refine in variants(args.variants).items()}
    when = {"after 1 move": 0, f"after {args.moves} moves": args.moves - 1}
    per_scene = {(name, w, label): [] for name in settings for w in when for label in ("prior", "refined")}
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
            for w, t in when.items():
                for label in ("prior", "refined"):
                    per_scene[name, w, label].append((truth.label[truth.target],
                                                      np.asarray(log.moves[t]["labels"][label])[truth.target]))
            times[name] += [m["times_ms"]["refinement"] for m in log.moves[1:]]
    M = len(object_set.classes)
    names = list(settings)
    rows, notes = [], []
    for name in names:
        row = [name]
        for w in when:
            for label in ("prior", "refined"):
                f1, lo, hi = metrics.scene_interval(per_scene[name, w, label], M)
                row.append(f"{f1:.3f} [{lo:.3f}, {hi:.3f}]")
        row.append(f"{np.median(times[name]):.0f}")
        rows.append(row)
    for w in when:
        for name in names[1:]:
            d, lo, hi = metrics.paired_difference(per_scene[names[0], w, "refined"], per_scene[name, w, "refined"], M)
            notes.append(f"Refined F1 {w}, the default minus {name!r}: {metrics.format_difference(d, lo, hi)}.")
        d, lo, hi = metrics.paired_difference(per_scene[names[0], w, "refined"], per_scene[names[0], w, "prior"], M)
        notes.append(f"Refined minus prior F1 {w}, the default: {metrics.format_difference(d, lo, hi)}.")
    report.publish(report.section(
        "The move's GR settings: F1 of the target objects, prior and refined", argv,
        ("GR setting", *(f"F1 {label} {w}" for w in when for label in ("prior", "refined")),
         "median GR ms per move (host, after the first)"), rows,
        intro=f"{args.scenes} held-out builtin scenes (seeds 100..), VisOcclHist, a random start view per scene, the "
              "same keys for every setting; 95% intervals and paired differences resample whole scenes.",
        notes=notes), args.out)


if __name__ == "__main__":
    main()
