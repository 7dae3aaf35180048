"""Geometric refinement batched over episodes: registrations per second of ``refine`` vmapped over B moves
(each 5 segments x top-3 classes x 8 yaws = 120 registrations), both DoF modes, on whatever JAX runs on.

    python benchmarks/refine_batched.py --save data/refine_moves.pkl        # once, where MuJoCo renders
    python benchmarks/refine_batched.py --moves data/refine_moves.pkl [--batch 64 256 1024] [--out BENCHMARKS.md]

``--save`` observes 3 views of held-out built-in scenes (``jaxcls.experiments.moves``, as ``benchmarks/refine.py``:
segments, the shipped classifier's scores, one model per class) and pickles the inputs with the model library's arrays,
so that the timing needs neither MuJoCo nor the object set (the GPU machine has neither). The timing tiles
the moves to B episodes and runs ``jax.jit(jax.vmap(refine.refine))`` over them: one call, all B x 120
registrations; medians over rounds after one warm-up call.
"""

from __future__ import annotations

import argparse
import datetime
import pickle
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import report
from jaxcls.perception import icp, refine


def save(path: Path, scenes: int) -> None:
    """Observe the moves (needs MuJoCo and the object set) and pickle refine's inputs."""
    from jaxcls.experiments.moves import observed_move
    from jaxcls.perception import pointnet

    classifier = pointnet.load_classifier()
    moves = []
    for seed in range(scenes):
        world, state, models, _ = observed_move(seed, classifier)
        moves.append({"points": np.asarray(state.segments.points), "mask": np.asarray(state.segments.mask),
                      "probs": np.asarray(state.probs), "table_height": world.table_height})
        if seed == 0:  # the batch shares one library (the first scene's: one model per class)
            moves[0]["library"] = jax.tree.map(np.asarray, refine.ModelLibrary.build(models, classifier.classes))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(moves))
    print(f"saved {len(moves)} moves to {path}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--save", type=Path, help="observe the moves and pickle refine's inputs here")
    parser.add_argument("--scenes", type=int, default=3, help="with --save: held-out scenes (one move each)")
    parser.add_argument("--moves", type=Path, help="time refine over the pickled moves")
    parser.add_argument("--batch", type=int, nargs="+", default=[64, 256, 1024], help="episodes per call")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    if args.save:
        return save(args.save, args.scenes)
    moves = pickle.loads(args.moves.read_bytes())
    grid_library = jax.tree.map(jnp.asarray, moves[0]["library"])  # one library for every episode of the batch
    variants = {"yaw (4-DoF), the default: 256 points, 3 + 9 iterations": refine.RefineConfig(),
                "6-DoF, 512 points, 5 + 15 iterations": refine.RefineConfig(
                    prune_after=5, icp=icp.ICPConfig(dof="full", iterations=20, points=512)),
                "yaw, the default, brute-force closest samples": refine.RefineConfig(
                    icp=icp.ICPConfig(iterations=12, points=256, lookup="brute"))}
    batched = jax.jit(jax.vmap(refine.refine, in_axes=(0, 0, 0, None, None, None)), static_argnums=(4,))
    rows = []
    for name, config in variants.items():
        for B in args.batch:
            library = grid_library.replace(targets=grid_library.targets.replace(
                brute=config.icp.lookup == "brute"))
            pick = [moves[b % len(moves)] for b in range(B)]
            points, mask, probs = (jnp.asarray(np.stack([m[k] for m in pick])) for k in ("points", "mask", "probs"))
            registrations = B * points.shape[1] * config.top_k * config.hypotheses
            start = time.perf_counter()
            jax.block_until_ready(batched(points, mask, probs, library, config, moves[0]["table_height"]))
            compile_s = time.perf_counter() - start
            times = []
            for _ in range(args.rounds):
                start = time.perf_counter()
                jax.block_until_ready(batched(points, mask, probs, library, config, moves[0]["table_height"]))
                times.append(time.perf_counter() - start)
            median = statistics.median(times)
            rows.append((name, report.device_name(), B, registrations, f"{1000 * median:.1f}",
                         f"{1000 * min(times):.1f}-{1000 * max(times):.1f}", f"{registrations / median:,.0f}",
                         f"{compile_s:.1f}"))
            print(rows[-1], flush=True)
    report.publish(report.section(
        f"Geometric refinement batched over episodes, {datetime.date.today()}", argv,
        ("DoF", "device", "episodes per call", "registrations per call", "median ms per call", "range",
         "registrations per second", "first call s (compile)"), rows,
        intro=f"`refine` vmapped over B moves ({len(moves)} observed moves tiled), {args.rounds} rounds; "
              "a registration is one of a move's 5 x 3 x 8 (segment, candidate, yaw) ICPs (all 8 yaws run "
              "`prune_after` iterations, the best per model the rest)."), args.out)


if __name__ == "__main__":
    main()
