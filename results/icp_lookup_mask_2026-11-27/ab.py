"""A/B in one process: GR of one move (benchmarks/refine.py's moves and default config) with ICP's closest-sample
lookup gathering its candidates' mask (A: before 2026-11-27) or not (B: now); each its own jitted program, traced
with its `_nearest_of`, then timed in interleaved rounds. Also checks that both give the same outputs.

    python results/icp_lookup_mask_2026-11-27/ab.py [--rounds 15] [--scenes 3]
"""
import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import report
from jaxcls.experiments.moves import observed_move
from jaxcls.perception import icp, pointnet, refine


def masked(target, x, candidates):  # the lookup as it was: points and mask gathered
    points, _, real = target._at(candidates)
    d2 = jnp.where(real, jnp.sum((points - x[:, None, :]) ** 2, axis=-1), jnp.inf)
    best = jnp.argmin(d2, axis=1)[:, None]
    return jnp.take_along_axis(candidates, best, axis=1)[:, 0], jnp.take_along_axis(d2, best, axis=1)[:, 0]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--scenes", type=int, default=3)
    args = parser.parse_args()
    classifier = pointnet.load_classifier()
    moves = [observed_move(seed, classifier) for seed in range(args.scenes)]
    config = refine.RefineConfig()
    libraries = [refine.ModelLibrary.build(models, classifier.classes, config.icp) for _, _, models, _ in moves]
    variants, outputs = {}, {}
    for name, nearest in (("A: points and mask gathered", masked), ("B: points only", icp._nearest_of)):
        program = jax.jit(refine.refine, static_argnames=("config",))
        original, icp._nearest_of = icp._nearest_of, nearest
        try:  # traced (and compiled) here, with this lookup
            outputs[name] = [jax.block_until_ready(program(s.segments.points, s.segments.mask, s.probs, lib, config,
                                                           w.table_height))
                             for (w, s, _, _), lib in zip(moves, libraries, strict=True)]
        finally:
            icp._nearest_of = original
        variants[name] = program
    a, b = (jax.tree.leaves(out) for out in outputs.values())
    same = all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(a, b, strict=True))
    times = {name: [] for name in variants}
    for r in range(args.rounds):
        for name in (variants if r % 2 == 0 else reversed(variants)):
            start = time.perf_counter()
            jax.block_until_ready([variants[name](s.segments.points, s.segments.mask, s.probs, lib, config,
                                                  w.table_height)
                                   for (w, s, _, _), lib in zip(moves, libraries, strict=True)])
            times[name].append((time.perf_counter() - start) / len(moves) * 1e3)
    print(f"{report.cpu_name()}, {args.scenes} moves a round, {args.rounds} interleaved rounds; "
          f"outputs identical: {same}")
    for name, t in times.items():
        print(f"{name}: median {statistics.median(t):.2f} ms a move (range {min(t):.2f}-{max(t):.2f})")


if __name__ == "__main__":
    main()
