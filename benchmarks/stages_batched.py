"""Where a batched move spends its time: each stage of ``active.step`` vmapped over B episodes and jitted on
its own, timed on states a few moves into their episodes (the profile behind whole moves/s).

    python benchmarks/episode_batched.py --save data/gpu/scene3.npz      # frames of one scene (needs MuJoCo)
    python benchmarks/stages_batched.py --frames data/gpu/scene3.npz --batch 256 1024 [--out BENCHMARKS.md]

Per batch size: the median ms of each stage (``active.STAGES``, ``arrive`` first) over ``--repeats`` calls,
its share of the move, and the whole move (``active.step`` vmapped, one jit) for comparison.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import precision, report
from jaxcls.episode import active, setup
from jaxcls.geometry import Intrinsics


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default="data/gpu/scene3.npz")
    parser.add_argument("--batch", type=int, nargs="+", default=[64, 256])
    parser.add_argument("--warm-moves", type=int, default=4, help="moves made before the stages are timed")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--storage", default="float32", choices=["float32", "compact"],
                        help="perception.volume.storage")
    parser.add_argument("--precision", default="float32", choices=["float32", "tf32"],
                        help="perception.classification_precision")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    precision.full_float32_matmuls()

    from jaxcls.world.objects import object_set_from_config
    from jaxcls.world.scenes import Scene

    with np.load(args.frames) as f:
        depth = jnp.asarray(f["depth_mm"].astype(np.float32) / 1000.0)
        T_wc = jnp.asarray(f["T_wc"], jnp.float32)
        scene = Scene.from_dict(json.loads(str(f["scene_json"])), source=args.frames)
    object_set = object_set_from_config(scene.object_set)
    perception = setup.episode_perception()
    perception = dataclasses.replace(perception, volume=dataclasses.replace(perception.volume, storage=args.storage),
                                     classification_precision=args.precision)
    episode = setup.make_episode(setup.ActiveConfig(perception=perception), object_set,
                                 Intrinsics.kinect_v1(depth.shape[2] / 640), scene.table_height)
    stages = (("arrive", active.arrive), *active.STAGES)
    vstep = jax.jit(jax.vmap(active.step, in_axes=(None, 0, 0, 0)))
    vstages = {name: jax.jit(jax.vmap(fn, in_axes=(None, 0, 0, 0))) for name, fn in stages}
    table = []
    for B in args.batch:
        starts = jnp.asarray(np.random.default_rng(B).integers(0, T_wc.shape[0], B), jnp.int32)
        keys = jax.random.split(jax.random.PRNGKey(B), B)
        state = jax.jit(jax.vmap(active.reset, in_axes=(None, None, 0, 0)))(episode, T_wc, starts, keys)
        for _ in range(args.warm_moves):
            state = vstep(episode, state, depth[state.next_view], T_wc[state.next_view])
        frame = (depth[state.next_view], T_wc[state.next_view])
        times: dict[str, list[float]] = {name: [] for name in ("move", *vstages)}
        inputs = {}
        s = state
        for name, fn in vstages.items():  # each stage's input: the state the stages before it left
            inputs[name] = s
            s = jax.block_until_ready(fn(episode, s, *frame))
        jax.block_until_ready(vstep(episode, state, *frame))
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(vstep(episode, state, *frame))
            times["move"].append(time.perf_counter() - t0)
            for name, fn in vstages.items():
                t0 = time.perf_counter()
                jax.block_until_ready(fn(episode, inputs[name], *frame))
                times[name].append(time.perf_counter() - t0)
        move = float(np.median(times["move"]))
        staged = sum(float(np.median(times[n])) for n in vstages)
        for name in ("move", *vstages):
            t = float(np.median(times[name]))
            share = "" if name == "move" else f"{t / staged:.2f}"
            table.append((B, name, report.device_name(), f"{t * 1e3:.1f}", f"{min(times[name]) * 1e3:.1f}-"
                          f"{max(times[name]) * 1e3:.1f}", share, f"{B / t:.0f}" if name == "move" else ""))
            print(table[-1], flush=True)
        print(f"B={B}: whole move {move * 1e3:.1f} ms, stages summed {staged * 1e3:.1f} ms", flush=True)
    report.publish(report.section(
        "A batched move, stage by stage", argv,
        ("episodes", "stage", "device", "median ms", "range ms", "share of the stages", "moves/s (whole move)"), table,
        intro=f"`active.step` and each of its stages vmapped over B episodes of scene {args.frames} (100 "
              f"viewpoints, 640x480), the episode's defaults with the volume stored {args.storage} and PointNet's "
              f"products {args.precision}, states {args.warm_moves} moves in."),
        args.out)


if __name__ == "__main__":
    main()
