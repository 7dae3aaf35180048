"""Scenes rendered on the GPU from the scene bank (``world.bank``: every instance in one MuJoCo model, a scene
as its mocap poses) against each scene's own model cast by MuJoCo's C caster on the host, as ``jaxcls dataset``
renders them: agreement and frames/s.

    python benchmarks/scene_bank.py --config synthetic --scenes 8 [--batch 512] [--kinematics static forward]
        [--out BENCHMARKS.md]

The scenes are the first ``--scenes`` of the dataset config (its seeds, its viewpoints). Agreement: the share of
pixels whose depth agrees within 1 mm (a return on both or neither) and whose object ids are equal. ``--kinematics``:
how the GPU poses the bank's meshes (``render.warp``): ``static``, the mocap poses applied in JAX (the default), or
``forward``, ``mjx.forward`` (collision and constraints over the parked slots included); each timed interleaved.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import numpy as np

from jaxcls import report
from jaxcls.config import load_config
from jaxcls.world import scenes
from jaxcls.world.bank import SceneBank
from jaxcls.world.dataset import DatasetConfig, scene_seeds
from jaxcls.world.objects import object_set_from_config
from jaxcls.world.setup import make_world


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="synthetic", help="a dataset config (name or path)")
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--batch", type=int, default=512, help="frames per renderer call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--kinematics", nargs="+", choices=("static", "forward"), default=["static"],
                        help="how the GPU poses the bank's meshes (render.warp); several: timed interleaved")
    parser.add_argument("--out", help="append the table to this Markdown file")
    args = parser.parse_args(argv)
    dataset = load_config(DatasetConfig, args.config)
    object_set = object_set_from_config(dataset.objects)
    seeds = scene_seeds(dataset.seed, dataset.num_scenes if args.scenes <= dataset.num_scenes else args.scenes)
    scene_list = [scenes.sample_scene(object_set, dataset.scene, seeds[i], dataset.objects) for i in range(args.scenes)]
    config = dataclasses.replace(dataset.world_config(), backend="mujoco")
    worlds = [make_world(config, scene=s, object_set=object_set) for s in scene_list]
    T_wc = np.stack([w.viewpoints for w in worlds])  # [S, V, 4, 4]
    S, V = T_wc.shape[:2]
    bank = SceneBank.build(object_set, dataset.scene, worlds[0].intrinsics)

    def native():
        return [w.render(np.arange(V)) for w in worlds]

    def on_gpu(kinematics: str):
        return lambda: jax.block_until_ready(bank.render(scene_list, T_wc, "warp", batch=args.batch,
                                                         kinematics=kinematics))

    contenders = {"native": native} | {f"warp, {k}": on_gpu(k) for k in args.kinematics}
    frames, first = {}, {}
    for name, fn in contenders.items():
        t0 = time.perf_counter()
        frames[name] = fn()
        first[name] = time.perf_counter() - t0
    ref_depth = np.stack([np.asarray(f.depth) for f in frames["native"]])
    ref_ids = np.stack([np.asarray(f.object_id) for f in frames["native"]])
    times = {name: [] for name in contenders}
    for _ in range(args.repeats):
        for name, fn in contenders.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    rows = []
    for name in contenders:
        t = float(np.median(times[name]))
        agreement = "(the reference)"
        if name != "native":
            depth, ids = np.asarray(frames[name].depth), np.asarray(frames[name].object_id)
            depth_ok = ((depth > 0) == (ref_depth > 0)) & (np.abs(depth - ref_depth) <= 1e-3)
            agreement = (f"{depth_ok.mean():.5f} / {(ids == ref_ids).mean():.5f} / "
                         f"{(ids == ref_ids)[(depth > 0) & (ref_depth > 0)].mean():.5f}")
        rows.append((name, report.cpu_name() if name == "native" else report.device_name(), S * V, f"{t:.2f}",
                     f"{min(times[name]):.2f}-{max(times[name]):.2f}", f"{S * V / t:.0f}",
                     "" if name == "native" else f"{first[name]:.1f}", agreement))
        print(rows[-1], flush=True)
    H, W = ref_depth.shape[2:]
    report.publish(report.section(
        f"Scenes rendered from the scene bank: {S} scenes x {V} views, {W}x{H}", argv,
        ("renderer", "device", "frames", "median s", "range s", "frames/s", "first call s (compile)",
         "agreement with native: depth within 1 mm / ids equal / ids equal where both hit"), rows,
        intro=f"Native: each scene's own model, MuJoCo's C caster on every host core (`jaxcls dataset`'s way); "
              f"warp: `SceneBank.render` ({len(bank.names)} slots, mocap poses per frame, {args.batch} frames a "
              f"call, object ids mapped back to each scene's), the bank's meshes posed by `static` (the mocap "
              f"poses applied in JAX) or `forward` (`mjx.forward`); {args.repeats} rounds, interleaved. Agreement: "
              f"shares of {ref_depth.size} pixels."),
        args.out)


if __name__ == "__main__":
    main()
