"""From how many viewing directions the lookalike set's pairs can be told apart: each held-out instance of a
class rendered alone from the 100 views of the hemisphere (radius 1 m, around its bounding box's centre, at a
random yaw), and again without the one part its lookalike lacks (the same draw: same body, same other parts).

    python experiments/lookalike_visibility.py [--instances 4] [--scenes 5] [--scale 1.0] [--min-pixels 30]
        [--out FILE]

Per view, two counts (pixels at ``--scale`` of 640 x 480, the threshold scaled to the Kinect's full resolution):
- the part is *seen*: at least ``--min-pixels`` of the part's own pixels are visible (MuJoCo's ray casting, the
  part its own body);
- the pair is *told apart*: at least ``--min-pixels`` pixels whose depth differs by more than ``--depth-step``
  (1 cm, about two TSDF voxels) between the two renderings, or that one of them sees and the other not.
A lid or a tube can be seen from low views and still hardly change the depth there (the open cup's far wall
stands right behind it), which the second count catches. Views are split at 30 degrees of elevation (the
Fibonacci lattice of ``geometry.hemisphere_viewpoints``: 50 views below, 50 above).

A second table (``--scenes``): the first scenes of ``configs/hard.yaml`` (10 objects, footprint gaps 2-12 mm),
each object's parts their own bodies, from the scene's 100 views: the share of views in which each part shows
at least ``--min-pixels`` pixels (the neighbours now hide it too), beside the share in which the object does.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics

import numpy as np
import trimesh

from jaxcls import geometry, report
from jaxcls.config import load_config
from jaxcls.world import scenes
from jaxcls.world.dataset import DatasetConfig, scene_seeds
from jaxcls.world.objects import ObjectModel, lookalike_object_set, lookalike_pairs
from jaxcls.world.objects.lookalike import model_parts
from jaxcls.world.render import make_renderer
from jaxcls.world.setup import make_world


@dataclasses.dataclass(frozen=True)
class PairViews:
    """One instance of a pair's lookalike seen from every view: elevation [V] rad, part [V] and differ [V]
    pixel counts (at the rendered resolution)."""

    elevation: np.ndarray
    part: np.ndarray
    differ: np.ndarray


def _posed_parts(lookalike: str, index: int, seed: int, yaw: float) -> dict[str, trimesh.Trimesh]:
    """The held-out instance's parts (its own only) as the set places them, turned by ``yaw`` rad about z."""
    parts = model_parts(lookalike, "test", index, seed)
    turn = np.eye(4)
    turn[:3, :3] = geometry.yaw_matrix_np(yaw)
    return {name: part.apply_transform(turn) for name, part in parts.items()}


def _render(parts: list[trimesh.Trimesh], intrinsics: geometry.Intrinsics, T_wc: np.ndarray) -> tuple[np.ndarray, ...]:
    """Depth [V, H, W] m and the part hit [V, H, W] (-1: table or nothing) of ``parts`` standing at the origin."""
    empty = np.zeros((1, 3), np.float32)
    bodies = [(ObjectModel(f"part_{i}", "part", mesh, empty, empty), f"part_{i}", np.eye(4))
              for i, mesh in enumerate(parts)]
    model = scenes.compile_model(bodies, 0.0, 0.75, intrinsics)
    frames = make_renderer(model, intrinsics, "mujoco").render(T_wc)
    return np.asarray(frames.depth), np.asarray(frames.object_id)


def pair_views(lookalike: str, part: str, index: int, seed: int, yaw: float, intrinsics: geometry.Intrinsics,
               views: int = 100, depth_step: float = 0.01) -> PairViews:
    """Held-out instance ``index`` of ``lookalike`` with and without ``part`` (metres, radians) from ``views``
    views of the hemisphere of radius 1 m around its bounding box's centre."""
    parts = _posed_parts(lookalike, index, seed, yaw)
    names = list(parts)
    centre = np.concatenate([np.asarray(p.vertices) for p in parts.values()])
    centre = (centre.min(axis=0) + centre.max(axis=0)) / 2
    T_wc = geometry.hemisphere_viewpoints(centre, views, 1.0)
    depth_with, hit = _render(list(parts.values()), intrinsics, T_wc)
    depth_without, _ = _render([parts[n] for n in names if n != part], intrinsics, T_wc)
    differ = (np.abs(depth_with - depth_without) > depth_step) | ((depth_with > 0) != (depth_without > 0))
    elevation = np.arcsin(np.clip((T_wc[:, 2, 3] - centre[2]), -1.0, 1.0))
    return PairViews(elevation=elevation, part=(hit == names.index(part)).sum(axis=(1, 2)),
                     differ=differ.sum(axis=(1, 2)))


def scene_part_views(dataset: DatasetConfig, seed: int,
                     intrinsics: geometry.Intrinsics) -> list[tuple[str, str, np.ndarray]]:
    """Scene ``seed`` of ``dataset`` from its viewpoints, every object's parts their own bodies: (class, part,
    visible pixels [V]) of each object (part ``object``: all its parts) and of each part besides its body."""
    world = make_world(dataset.world_config(), seed)
    empty = np.zeros((1, 3), np.float32)
    bodies, owner = [], []
    for k, (model, T) in enumerate(zip(world.models, world.scene.object_poses(), strict=True)):
        split, index = ("test", model.name.split("_test_")[1]) if "_test_" in model.name else (
            "train", model.name.rsplit("_", 1)[1])
        for name, mesh in model_parts(model.class_name, split, int(index), dataset.objects.seed).items():
            bodies.append((ObjectModel(f"{k}_{name}", "part", mesh, empty, empty), f"{k}_{name}", T))
            owner.append((k, model.class_name, name))
    mj = scenes.compile_model(bodies, world.scene.table_height, world.scene.table_half_size, intrinsics)
    ids = np.asarray(make_renderer(mj, intrinsics, "mujoco").render(world.viewpoints).object_id)
    counts = np.stack([np.bincount(v.ravel() + 1, minlength=len(bodies) + 1)[1:] for v in ids])  # [V, B]
    out = []
    for k in range(len(world.models)):
        mine = [j for j, (o, _, _) in enumerate(owner) if o == k]
        out.append((owner[mine[0]][1], "object", counts[:, mine].sum(axis=1)))
        out += [(owner[j][1], owner[j][2], counts[:, j]) for j in mine if owner[j][2] != "body"]
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--instances", type=int, default=4, help="held-out instances of each lookalike")
    parser.add_argument("--seed", type=int, default=0, help="the set's seed (objects.seed)")
    parser.add_argument("--scale", type=float, default=1.0, help="of 640 x 480")
    parser.add_argument("--min-pixels", type=int, default=30, help="at 640 x 480 (scaled with --scale^2)")
    parser.add_argument("--depth-step", type=float, default=0.01, help="m")
    parser.add_argument("--scenes", type=int, default=5, help="of configs/hard.yaml (0: none)")
    parser.add_argument("--out", help="append the section to this Markdown file")
    args = parser.parse_args(argv)
    lookalike_object_set(args.seed, 0, args.instances)  # builds every instance: its size checks
    intrinsics = geometry.Intrinsics.kinect_v1(args.scale)
    least = max(1, round(args.min_pixels * args.scale**2))
    yaws = np.random.default_rng(args.seed).uniform(-np.pi, np.pi, args.instances)
    rows = []
    for base, lookalike, part in lookalike_pairs():
        seen, apart, low, high = [], [], [], []
        for i in range(args.instances):
            v = pair_views(lookalike, part, i, args.seed, float(yaws[i]), intrinsics, depth_step=args.depth_step)
            told = v.differ >= least
            seen.append(float(np.mean(v.part >= least)))
            apart.append(float(np.mean(told)))
            low.append(float(np.mean(told[v.elevation < np.radians(30)])))
            high.append(float(np.mean(told[v.elevation >= np.radians(30)])))
        rows.append((f"{base} / {lookalike}", part, f"{statistics.mean(seen):.2f}",
                     f"{statistics.mean(apart):.2f}", f"{min(apart):.2f}-{max(apart):.2f}",
                     f"{statistics.mean(low):.2f}", f"{statistics.mean(high):.2f}"))
    report.publish(report.section(
        "Lookalike pairs: the share of the 100 views that tell them apart", argv,
        ("pair", "the part", "views seeing the part", "views telling them apart (mean)", "over instances",
         "below 30 deg elevation", "at 30 deg and above"),
        rows, intro=f"Each of the first {args.instances} held-out instances of a pair's lookalike (seed "
                    f"{args.seed}, a random yaw each) alone on the table, rendered by MuJoCo at "
                    f"{intrinsics.width} x {intrinsics.height} from the 100 views of the hemisphere (1 m, around its "
                    f"bounding box's centre), with and without the part; a view counts when at least "
                    f"{args.min_pixels} pixels (at 640 x 480) show the part, or differ in depth by more than "
                    f"{args.depth_step * 100:g} cm."), args.out)
    if not args.scenes:
        return
    dataset = load_config(DatasetConfig, "hard")
    shares: dict[tuple[str, str], list[float]] = {}
    for seed in scene_seeds(dataset.seed, args.scenes):
        for class_name, part, pixels in scene_part_views(dataset, seed, intrinsics):
            shares.setdefault((class_name, part), []).append(float(np.mean(pixels >= least)))
    rows = []
    for base, lookalike, part in lookalike_pairs():
        seen, whole = shares.get((lookalike, part), []), shares.get((lookalike, "object"), [])
        rows.append((f"{base} / {lookalike}", part, len(seen), f"{statistics.mean(seen):.2f}" if seen else "-",
                     f"{min(seen):.2f}-{max(seen):.2f}" if seen else "-",
                     f"{statistics.mean(whole):.2f}" if whole else "-"))
    report.publish(report.section(
        "Lookalike pairs in the hard scenes: the share of the 100 views that see the part", argv,
        ("pair", "the part", "objects", "views seeing the part (mean)", "over objects", "views seeing the object"),
        rows, intro=f"The first {args.scenes} scenes of `configs/hard.yaml` (10 objects of the held-out instances, "
                    f"footprint gaps 2-12 mm), every object's parts their own bodies, rendered by MuJoCo at "
                    f"{intrinsics.width} x {intrinsics.height} from the scene's 100 views; a view counts when at least "
                    f"{args.min_pixels} pixels (at 640 x 480) show the lookalike's part (or, last column, the "
                    "object)."), args.out)


if __name__ == "__main__":
    main()
