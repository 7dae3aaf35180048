"""Table 1's policy rows two ways, interleaved in one process: each row its own program run scene by scene
(``protocol.rollouts``: a scene's runs vmapped, one compiled program per row), against one switched program for
every row batched over scenes and runs and sharded over the local devices (``episode.batched``).

    python benchmarks/episode_batched.py --save data/gpu/scene3.npz      # frames of one scene (needs MuJoCo)
    python benchmarks/rows_batched.py --frames data/gpu/scene3.npz --scenes 64 --runs 10 [--out BENCHMARKS.md]

The scene's frames stand for ``--scenes`` scenes (copies: the work per episode is a real scene's; the start
views and keys differ per copy as Table 1's do). Reports per path: the compile time (first pass over the rows
minus a steady pass), the steady wall time per pass over every row and the whole moves/s; the records of the
two paths are compared (paths and refined labels of every episode).
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import precision, report
from jaxcls.episode import active, batched, protocol, setup
from jaxcls.geometry import Intrinsics

ROWS = ("random", "random_gr", "vis_occl_hist", "vis_occl_hist_gr")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default="data/gpu/scene3.npz")
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--moves", type=int, default=10)
    parser.add_argument("--rows", nargs="+", default=list(ROWS))
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--batched-only", action="store_true", help="skip the per-scene path (batch scaling)")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    precision.full_float32_matmuls()

    from jaxcls.world.objects import object_set_from_config
    from jaxcls.world.scenes import Scene

    with np.load(args.frames) as f:
        depth = f["depth_mm"].astype(np.float32) / 1000.0
        T_wc = np.asarray(f["T_wc"], np.float32)
        scene = Scene.from_dict(json.loads(str(f["scene_json"])), source=args.frames)
    object_set = object_set_from_config(scene.object_set)
    S, R, V = args.scenes, args.runs, len(T_wc)
    base = setup.ActiveConfig(episode=active.EpisodeConfig(moves=args.moves))
    rows = {name: protocol.row(name) for name in args.rows}
    classifier = setup.load_classifier("", object_set)
    intrinsics = Intrinsics.kinect_v1(depth.shape[2] / 640)  # the frames' resolution, the Kinect's field of view
    own = {name: row.episode(base, args.moves, classifier, object_set, intrinsics, scene.table_height)
           for name, row in rows.items()}
    policies = tuple(dict.fromkeys(row.policy for row in rows.values()))
    switched = own[args.rows[0]].switched(policies)
    starts = np.stack([protocol.start_views(0, s, R, V) for s in range(S)])  # [S, R]
    keys = np.stack([np.asarray(protocol.run_keys(0, s, R)) for s in range(S)])  # [S, R, 2]
    depth_d, T_wc_d = jnp.asarray(depth), jnp.asarray(T_wc)
    stacked_depth, stacked_T = jnp.broadcast_to(depth_d, (S, *depth.shape)), jnp.broadcast_to(T_wc_d, (S, *T_wc.shape))
    device_mesh = batched.mesh()

    def per_scene() -> dict:
        out = {}
        for name in rows:
            t0 = time.perf_counter()
            out[name] = [jax.device_get(protocol.rollouts(own[name], depth_d, T_wc_d, starts[s], keys[s]))
                         for s in range(S)]
            print(f"  per scene, {name}: {time.perf_counter() - t0:.1f} s", flush=True)
        return out

    def one_program() -> dict:
        out = {}
        for name, row in rows.items():
            t0 = time.perf_counter()
            traces = batched.rollouts(switched.choose(row.policy, row.refinement), stacked_depth, stacked_T,
                                      np.repeat(np.arange(S), R), starts.reshape(-1), keys.reshape(S * R, -1),
                                      device_mesh)
            print(f"  one program, {name}: {time.perf_counter() - t0:.1f} s", flush=True)
            out[name] = [jax.tree.map(lambda x, s=s: x[s * R:(s + 1) * R], traces) for s in range(S)]
        return out

    paths = {"per scene, a program per row": per_scene, "batched, one program": one_program}
    if args.batched_only:
        del paths["per scene, a program per row"]
    first, steady, result = {}, {p: [] for p in paths}, {}
    for name, run in paths.items():
        t0 = time.perf_counter()
        result[name] = run()
        first[name] = time.perf_counter() - t0
    for _ in range(args.repeats):
        for name, run in paths.items():
            t0 = time.perf_counter()
            run()
            steady[name].append(time.perf_counter() - t0)
    a, b = result[next(iter(paths))], result["batched, one program"]
    same = sum(np.array_equal(a[n][s].view, b[n][s].view) and np.array_equal(a[n][s].refinement.refined,
                                                                             b[n][s].refinement.refined)
               for n in rows for s in range(S))
    moves = S * R * args.moves * len(rows)
    table = []
    for name in paths:
        t = float(np.median(steady[name]))
        table.append((name, report.device_name(), len(jax.local_devices()), f"{first[name] - t:.1f}", f"{t:.2f}",
                      f"{min(steady[name]):.2f}-{max(steady[name]):.2f}", f"{moves / t:.0f}"))
        print(table[-1], flush=True)
    report.publish(report.section(
        f"Table 1's policy rows: {len(rows)} rows x {S} scenes x {R} runs x {args.moves} moves", argv,
        ("path", "device", "devices", "compile s (first pass - steady)", "median s per pass", "range s",
         "whole moves/s"), table,
        intro=f"Frames of {args.frames} in device memory; {same} of {len(rows) * S} (row, scene) groups of runs "
              "have the same paths and refined labels on both paths (a differing tie of the utility or of "
              "rho in the last float32 digits changes a path)."),
        args.out)


if __name__ == "__main__":
    main()
