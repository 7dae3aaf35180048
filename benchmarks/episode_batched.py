"""Whole episodes batched on one device: ``active.rollout`` (T moves under one ``lax.scan``) vmapped over
episodes of one scene from different start views, as issue 23's larger runs will use it.

    python benchmarks/episode_batched.py --save data/gpu/scene3.npz          # on a machine with MuJoCo
    python benchmarks/episode_batched.py --frames data/gpu/scene3.npz --batch 1 16 64 [--out BENCHMARKS.md]
        [--tracking frame_to_model reported]

Reports episodes/s and moves/s per batch size and camera tracking (``perception.tracking.mode``: each
batch size runs every mode, their repeats interleaved), the first call (compilation), and the final F1 of the
target objects pooled over the batch (prior and refined); ``--trace FILE`` writes each episode's path and
final labels (JSON) to compare with another device.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import io, metrics, precision, report
from jaxcls.episode import active, scoring, setup
from jaxcls.geometry import Intrinsics


def save_frames(path: str, seed: int) -> None:
    """Render scene ``seed`` of the default world from every viewpoint (depth in mm, uint16) to ``path``."""
    from jaxcls.world import WorldConfig, make_world

    world = make_world(WorldConfig(backend="mujoco"), seed=seed)
    depth, T_wc, _, _ = world.measure(jax.random.PRNGKey(seed), np.arange(len(world.viewpoints)))
    with io.atomic_write(path) as f:
        np.savez_compressed(f, depth_mm=np.round(depth * 1000).astype(np.uint16), T_wc=T_wc,
                            scene_json=np.array(json.dumps(world.scene.to_dict())))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default="data/gpu/scene3.npz")
    parser.add_argument("--save", help="render the frames file here (needs MuJoCo) and stop")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 16, 64])
    parser.add_argument("--moves", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--trace", help="write each episode's path and final labels (JSON) here")
    parser.add_argument("--tracking", nargs="+", default=["frame_to_model"], choices=["frame_to_model", "reported"],
                        help="perception.tracking.mode of the episodes (several: compared, interleaved)")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    if args.save:
        save_frames(args.save, args.seed)
        print(f"wrote {args.save}")
        return
    precision.full_float32_matmuls()  # camera poses need it on GPUs

    from jaxcls.world.objects import object_set_from_config
    from jaxcls.world.scenes import Scene

    with np.load(args.frames) as f:
        depth = jnp.asarray(f["depth_mm"].astype(np.float32) / 1000.0)
        T_wc = jnp.asarray(f["T_wc"], jnp.float32)
        scene = Scene.from_dict(json.loads(str(f["scene_json"])), source=args.frames)
    object_set = object_set_from_config(scene.object_set)
    truth = scoring.Truth.from_scene(scene, object_set)
    perception = setup.episode_perception()
    episodes = {}
    for mode in args.tracking:
        settings = setup.ActiveConfig(episode=active.EpisodeConfig(moves=args.moves), perception=dataclasses.replace(
            perception, tracking=dataclasses.replace(perception.tracking, mode=mode)))
        episodes[mode] = setup.make_episode(settings, object_set, Intrinsics.kinect_v1(), scene.table_height)
    reset = jax.jit(jax.vmap(active.reset, in_axes=(None, None, 0, 0)))
    rollout = jax.jit(jax.vmap(active.rollout, in_axes=(None, 0, None, None)))
    rows, traces = [], []
    M = len(object_set.classes)
    for B in args.batch:
        starts = jnp.asarray(np.random.default_rng(B).integers(0, T_wc.shape[0], B), jnp.int32)
        keys = jax.random.split(jax.random.PRNGKey(B), B)
        first, times, final, trace = {}, {m: [] for m in episodes}, {}, {}
        for mode, episode in episodes.items():
            t0 = time.perf_counter()
            final[mode], trace[mode] = jax.block_until_ready(rollout(episode, reset(episode, T_wc, starts, keys),
                                                                     depth, T_wc))
            first[mode] = time.perf_counter() - t0
        for _ in range(args.repeats):
            for mode, episode in episodes.items():
                t0 = time.perf_counter()
                jax.block_until_ready(rollout(episode, reset(episode, T_wc, starts, keys), depth, T_wc))
                times[mode].append(time.perf_counter() - t0)
        for mode in episodes:
            t = float(np.median(times[mode]))
            true, predicted = [], []  # per episode: the targets' true and [prior, refined] labels
            for b in range(B):
                r = jax.tree.map(lambda a, b=b: np.asarray(a[b]), final[mode].refinement)
                centroid = np.asarray(active.centroids(jax.tree.map(lambda a, b=b: a[b], final[mode].observation)))
                labels = scoring.object_labels(truth, centroid, r.valid, np.stack([r.prior, r.refined]))
                predicted.append(labels[:, truth.target])
                true.append(truth.label[truth.target])
            true, predicted = np.concatenate(true), np.concatenate(predicted, axis=1)
            scores = {label: metrics.classification_scores(true, predicted[i], M).f1
                      for i, label in enumerate(("prior", "refined"))}
            rows.append((B, mode, report.device_name(), f"{first[mode]:.1f}", f"{t * 1e3:.0f}", f"{B / t:.1f}",
                         f"{B * args.moves / t:.0f}", f"{scores['prior']:.3f}", f"{scores['refined']:.3f}"))
            print(rows[-1], flush=True)
            traces += [{"batch": B, "tracking": mode, "start": int(starts[b]),
                        "path": np.asarray(trace[mode].view[b]).tolist(),
                        "refined": np.asarray(final[mode].refinement.refined[b]).tolist(),
                        "valid": np.asarray(final[mode].refinement.valid[b]).tolist()} for b in range(min(B, 16))]
    if args.trace:
        io.write_json(args.trace, traces)
    report.publish(report.section(
        f"Whole episodes batched ({args.moves} moves, 640x480, one scene)", argv,
        ("episodes", "tracking", "device", "first call s (compile)", "median ms per batch", "episodes/s", "moves/s",
         "F1 prior (pooled)", "F1 refined (pooled)"), rows,
        intro=f"`active.rollout` vmapped over episodes from random start views of scene {args.frames} (100 "
              "viewpoints), the episode's defaults (`setup.ActiveConfig()`); frames in device memory."),
        args.out)


if __name__ == "__main__":
    main()
