"""Labelled point clouds of single objects, for training and evaluating the classifier (paper Sec. 4).

Five sources, each a cloud of one instance in a z-up frame:

- ``full``: the paper's recipe, points sampled uniformly on the instance's complete surface (model frame);
- ``view``: one rendered depth frame of the instance alone on the table, from a random viewpoint, its
  pixels back-projected (what a single-view segment looks like; the paper's PointNetSingle input);
- ``occluded``: the same, with 1-3 other instances placed around it (only its visible pixels);
- ``fused``: 2-3 such frames fused into a TSDF and its surface extracted (a partial reconstruction);
- ``scene``: what the loop feeds the classifier: segments that ``perception.observe`` cuts out of a
  cluttered scene of the split's instances after 1-10 fused views, labelled by their majority object and
  kept when pure enough (``CloudConfig.scenes``; off by default).

Clouds are stored centred on their mean (the classifier normalises position and scale away), in float16.
They are made with the perception settings of the loop they train for (``PerceptionConfig``: the table
band of ``foreground``, the TSDF ``volume``): points at or below the table band are dropped, as the
loop's foreground drops them, and fused clouds come from ``perception.observation.fuse``.
Rendering uses the configured backend (``mujoco`` on the CPU; ``warp`` on a GPU). Clouds of each instance
(and of each scene) are cached in one file under ``cache_dir``, so an interrupted generation resumes where
it stopped.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from pathlib import Path
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from jaxcls import geometry, io, parallel
from jaxcls.config import bounded, check_bounds
from jaxcls.perception import foreground, observation, tsdf
from jaxcls.perception.settings import PerceptionConfig, Spec
from jaxcls.planning import nbv
from jaxcls.world.objects import ObjectModel, ObjectSet, ObjectSetConfig
from jaxcls.world.render.sensor import SensorConfig
from jaxcls.world.render.types import Backend
from jaxcls.world.scenes import SceneConfig

SOURCES = ("full", "view", "occluded", "fused", "scene")
_CACHE_VERSION = 2  # bump when the way clouds are made changes (scene layout, volume, intrinsics)
_FUSED_SURFACE_POINTS = 8192  # surface points extracted for a fused cloud of one instance
# The table and spacing clouds are rendered with: the world's default (its height is the scenes' own).
_SCENE = SceneConfig()
_TOUCHING_GAPS = {"min_gap": 0.001, "max_gap": 0.005}  # the scene source's touching scenes (below a voxel)


@dataclasses.dataclass(frozen=True)
class CloudConfig:
    """How many clouds of each source an instance gets, and how they are made (``data:`` in the config)."""

    full_points: int = bounded(2500, ge=1)  # the paper's 2500 surface samples per instance
    full_per_instance: int = bounded(1, ge=0)
    views_per_instance: int = bounded(16, ge=0)
    occluded_per_instance: int = bounded(8, ge=0)
    fused_per_instance: int = bounded(4, ge=0)
    max_points: int = bounded(1024, ge=1)  # points kept per partial cloud (a random subset of larger clouds)
    min_points: int = bounded(64, ge=1)  # a view showing fewer points of the instance is drawn again
    image_scale: float = bounded(0.5, gt=0.0, le=4.0)  # of the Kinect v1 (0.5 = 320x240)
    radius: tuple[float, float] = bounded((0.7, 1.2), gt=0.0)  # camera distance [low, high], m
    elevation_deg: tuple[float, float] = bounded((10.0, 80.0), ge=0.0, le=90.0)  # [low, high]
    # The "scene" source: segments that ``perception.observe`` cuts out of cluttered scenes of the split's
    # instances, fused along a random path of 1..scene_max_views views, labelled by their majority object
    # and kept when that object holds >= scene_purity of their points (what the loop feeds the network).
    scenes: int = bounded(0, ge=0)
    scene_max_views: int = bounded(10, ge=1)
    scene_purity: float = bounded(0.8, ge=0.0, le=1.0)
    # What the scenes look like: a fraction with touching objects (footprint gaps 1-5 mm, below a voxel, as
    # the in-scene evaluation's "touching" world) and a fraction seen through the Kinect-v1 sensor model
    # with hand-eye error (its "real_like" world); the rest ideal depth with gaps of 3 mm - 3 cm.
    scene_touching: float = bounded(0.0, ge=0.0, le=1.0)
    scene_noisy: float = bounded(0.0, ge=0.0, le=1.0)
    backend: Backend = Backend.auto
    cache_dir: str = "data/clouds"
    # Worker processes making the missing instances' and scenes' clouds (each writes its own file; the same
    # clouds as one process makes): more than 1 renders with the CPU renderer (``mujoco``) and runs JAX on the CPU.
    workers: int = bounded(1, ge=1)

    def __post_init__(self) -> None:
        check_bounds(self, "data.")
        if (self.full_per_instance + self.views_per_instance + self.occluded_per_instance
                + self.fused_per_instance + self.scenes) == 0:
            raise ValueError("data: full_per_instance, views_per_instance, occluded_per_instance, "
                             "fused_per_instance and scenes are all 0: no clouds would be made")
        for name in ("radius", "elevation_deg"):
            low, high = getattr(self, name)
            if low > high:
                raise ValueError(f"data.{name} must be [low, high] with low <= high, got {[low, high]}")
        if self.scene_touching + self.scene_noisy > 1.0:
            raise ValueError(f"data.scene_touching + data.scene_noisy = {self.scene_touching + self.scene_noisy}"
                             " must be <= 1 (they are fractions of the scenes)")
        if round(480 * self.image_scale) < 1:
            raise ValueError(f"data.image_scale = {self.image_scale} makes images under one pixel high")


@dataclasses.dataclass(frozen=True)
class CloudSet:
    """Clouds padded to one size (NumPy, host side).

    points: [C, S, 3] f32 m (0 where padded); mask: [C, S] bool; label: [C] i32 class index;
    source: [C] i32 index into ``SOURCES``; instance: [C] i32 index of the instance in its split; yaw: [C]
    f32 rad, the instance's yaw about z in the cloud's frame (its model frame turned by this; the yaw head's
    target).
    """

    points: np.ndarray
    mask: np.ndarray
    label: np.ndarray
    source: np.ndarray
    instance: np.ndarray
    yaw: np.ndarray

    def __len__(self) -> int:
        return len(self.label)

    def select(self, keep: np.ndarray) -> CloudSet:
        return CloudSet(*(getattr(self, f.name)[keep] for f in dataclasses.fields(self)))

    @staticmethod
    def concatenate(parts: list[CloudSet]) -> CloudSet:
        return CloudSet(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(CloudSet)))


def _pad(clouds: list[np.ndarray], size: int) -> tuple[np.ndarray, np.ndarray]:
    points = np.zeros((len(clouds), size, 3), np.float32)
    mask = np.zeros((len(clouds), size), bool)
    for i, c in enumerate(clouds):
        points[i, :len(c)], mask[i, :len(c)] = c, True
    return points, mask


def _subset(points: np.ndarray, size: int, rng: np.random.Generator) -> np.ndarray:
    """At most ``size`` of ``points: [n, 3]``, in random order."""
    return points[rng.permutation(len(points))[:size]].astype(np.float32)


def _random_views(rng: np.random.Generator, target: np.ndarray, count: int, config: CloudConfig) -> np.ndarray:
    """[count, 4, 4] ``T_wc`` on the upper hemisphere around ``target`` at random distance and elevation."""
    elevation = np.radians(rng.uniform(*config.elevation_deg, count))
    azimuth = rng.uniform(0, 2 * math.pi, count)
    radius = rng.uniform(*config.radius, count)
    direction = np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                          np.sin(elevation)], axis=-1)
    aim = target + rng.normal(0.0, 0.01, (count, 3))  # the object is not always at the image centre
    return geometry.look_at(aim + radius[:, None] * direction, aim)


def _visible_points(depth: np.ndarray, object_id: np.ndarray, index: int, intrinsics: geometry.Intrinsics,
                    T_wc: np.ndarray, table_top: float) -> np.ndarray:
    """[n, 3] world points of the pixels that see object ``index``, above the table band."""
    points = np.asarray(geometry.backproject(jnp.asarray(depth), intrinsics, jnp.asarray(T_wc, jnp.float32)))
    points = points[(object_id == index) & (depth > 0)]
    return points[points[:, 2] > table_top]


class _InstanceRenderer:
    """Renders clouds of one instance: alone, among occluders, fused."""

    def __init__(self, model: ObjectModel, pool: tuple[ObjectModel, ...], object_set_config: ObjectSetConfig,
                 config: CloudConfig, rng: np.random.Generator, perception: PerceptionConfig):
        from jaxcls.world.render import resolve_backend  # here, not at the top: cached clouds need no MuJoCo

        self.model, self.pool, self.config, self.rng = model, pool, config, rng
        self.object_set_config = object_set_config
        self.intrinsics = geometry.Intrinsics.kinect_v1(config.image_scale)
        self.scene_config = _SCENE
        self.spec = Spec.create(perception, self.intrinsics, table_height=self.scene_config.table_height)
        self.table_top = self.spec.floor
        self.backend = resolve_backend(config.backend)

    def _scene(self, others: tuple[ObjectModel, ...]):
        """(renderer, index of the instance, its centre [3], its pose [4, 4]) with ``others`` placed around it."""
        from jaxcls.world import scenes
        from jaxcls.world.render import make_renderer

        models = (self.model, *others)
        scene = scenes.arrange_scene(models, self.scene_config, int(self.rng.integers(2**31)),
                                     self.object_set_config)
        by_name = {m.name: m for m in models}
        placed = tuple(by_name[o.name] for o in scene.objects)
        renderer = make_renderer(scenes.build_model(scene, placed, self.intrinsics), self.intrinsics, self.backend)
        index = [o.name for o in scene.objects].index(self.model.name)
        pose = scene.object_poses()[index]
        return renderer, index, (pose @ np.append(self.model.bounds.mean(axis=0), 1.0))[:3], pose

    def _views(self, renderer, index: int, centre: np.ndarray, count: int) -> tuple[list, list]:
        """Up to ``count`` views showing >= min_points of the instance (a few tries): (clouds [n, 3] m,
        frames (depth [H, W] m, T_wc [4, 4]))."""
        clouds, frames = [], []
        for _ in range(4):
            need = count - len(clouds)
            if need <= 0:
                break
            Ts = _random_views(self.rng, centre, 2 * need, self.config)
            rendered = renderer.render(Ts)
            depth, ids = np.asarray(rendered.depth), np.asarray(rendered.object_id)
            for d, o, T in zip(depth, ids, Ts, strict=True):
                pts = _visible_points(d, o, index, self.intrinsics, T, self.table_top)
                if len(pts) >= self.config.min_points and len(clouds) < count:
                    clouds.append(pts)
                    frames.append((d, T))
        return clouds, frames

    def single(self) -> tuple[list[np.ndarray], list[float]]:
        """(clouds, the instance's yaw in each)."""
        if self.config.views_per_instance == 0:
            return [], []
        renderer, index, centre, pose = self._scene(())
        clouds, _ = self._views(renderer, index, centre, self.config.views_per_instance)
        return clouds, [_yaw(pose)] * len(clouds)

    def occluded(self) -> tuple[list[np.ndarray], list[float]]:
        clouds: list[np.ndarray] = []
        yaws: list[float] = []
        others = [m for m in self.pool if m is not self.model]
        for _ in range(self.config.occluded_per_instance):
            picks = self.rng.choice(len(others), size=min(len(others), int(self.rng.integers(1, 4))), replace=False)
            renderer, index, centre, pose = self._scene(tuple(others[k] for k in picks))
            seen = self._views(renderer, index, centre, 1)[0]
            clouds += seen
            yaws += [_yaw(pose)] * len(seen)
        return clouds, yaws

    def fused(self) -> tuple[list[np.ndarray], list[float]]:
        if self.config.fused_per_instance == 0:
            return [], []
        renderer, index, centre, pose = self._scene(())
        empty = observation.empty_volume(self.spec)
        clouds = []
        for _ in range(self.config.fused_per_instance):
            _, frames = self._views(renderer, index, centre, int(self.rng.integers(2, 4)))
            volume = empty
            for depth, T in frames:
                volume = observation.fuse(self.spec, volume, depth, T)
            surface = tsdf.extract_surface(volume, _FUSED_SURFACE_POINTS)
            keep = np.asarray(foreground.foreground_mask(self.spec, surface.points, surface.mask))
            pts = np.asarray(surface.points)[keep]
            if len(pts) >= self.config.min_points:
                clouds.append(pts)
        return clouds, [_yaw(pose)] * len(clouds)


def _yaw(pose: np.ndarray) -> float:
    """The yaw about z (rad) of an upright model-to-world ``pose`` [4, 4]."""
    return float(np.arctan2(pose[1, 0], pose[0, 0]))


def instance_clouds(model: ObjectModel, pool: tuple[ObjectModel, ...], label: int, object_set_config: ObjectSetConfig,
                    config: CloudConfig, seed: int, perception: PerceptionConfig | None = None) -> CloudSet:
    """Every source's clouds of one instance (``pool``: the instances occluders are drawn from)."""
    rng = np.random.default_rng(seed)
    full = [_subset(model.surface_points, config.full_points, rng) for _ in range(config.full_per_instance)]
    maker = _InstanceRenderer(model, pool, object_set_config, config, rng, perception or PerceptionConfig())
    by_source = {"full": (full, [0.0] * len(full)), "view": maker.single(), "occluded": maker.occluded(),
                 "fused": maker.fused(), "scene": ([], [])}  # scene clouds are made per scene (``scene_clouds``)
    clouds = [_subset(c, config.max_points if s != "full" else config.full_points, rng)
              for s in SOURCES for c in by_source[s][0]]
    clouds = [c - c.mean(axis=0) for c in clouds]
    source = np.concatenate([np.full(len(by_source[s][0]), i, np.int32) for i, s in enumerate(SOURCES)])
    yaw = np.asarray([y for s in SOURCES for y in by_source[s][1]], np.float32)
    points, mask = _pad(clouds, max(config.max_points, config.full_points))
    return CloudSet(points, mask, np.full(len(clouds), label, np.int32), source, np.zeros(len(clouds), np.int32),
                    yaw)


def scene_clouds(object_set: ObjectSet, split: Literal["train", "test"], object_set_config: ObjectSetConfig,
                 config: CloudConfig, seed: int, perception: PerceptionConfig | None = None) -> CloudSet:
    """The "scene" source of one cluttered scene of ``split``'s instances (see ``CloudConfig``): each pure
    segment of ``perception.observe`` after a random path of 1..``scene_max_views`` views, centred, at most
    ``max_points`` points, labelled with its majority object's class and that instance's index in the split."""
    from jaxcls import metrics
    from jaxcls.perception.observation import init_state, observe
    from jaxcls.world.setup import WorldConfig, make_world

    rng = np.random.default_rng(seed)
    kind = rng.random()  # touching, noisy or plain (see CloudConfig.scene_touching / scene_noisy)
    touching = kind < config.scene_touching
    noisy = not touching and kind < config.scene_touching + config.scene_noisy
    # As many objects as the scenes of the loop, or every instance of a small split (one model per class).
    scene = dataclasses.replace(_SCENE, split=split, num_objects=min(_SCENE.num_objects, len(object_set.split(split))),
                                **(_TOUCHING_GAPS if touching else {}))
    sensor = SensorConfig(pose_noise=True, pose_noise_shared=True) if noisy else SensorConfig.ideal()
    world = make_world(WorldConfig(objects=object_set_config, scene=scene, sensor=sensor, backend=config.backend,
                                   camera=geometry.CameraConfig.kinect_v1(config.image_scale)),
                       int(rng.integers(2**31)), object_set=object_set)
    spec = Spec.create(perception or PerceptionConfig(), world.intrinsics, world.table_height)
    path = nbv.random_walk(rng, world.viewpoints, int(rng.integers(1, config.scene_max_views + 1)))
    depths, poses, _, _ = world.measure(jax.random.key(int(rng.integers(2**31))), path)
    state = init_state(spec)
    for depth, T in zip(depths, poses, strict=True):
        state = observe(spec, state, depth, T)
    points, mask = np.asarray(state.segments.points), np.asarray(state.segments.mask)
    owners = metrics.PointOwners(world.scene, world.models)
    truth = metrics.segment_truth(owners(points.reshape(-1, 3), mask.reshape(-1)).reshape(mask.shape), mask)
    keep = np.flatnonzero((truth.object >= 0) & (truth.purity >= config.scene_purity)
                          & (truth.size >= config.min_points))
    members = object_set.split(split)
    clouds = [_subset(points[n][mask[n]], config.max_points, rng) for n in keep]
    clouds = [c - c.mean(axis=0) for c in clouds]
    label = [object_set.class_index(world.scene.objects[truth.object[n]].class_name) for n in keep]  # no clutter
    instance = [members.index(world.models[truth.object[n]]) for n in keep]
    yaw = [world.scene.objects[truth.object[n]].yaw for n in keep]
    padded, padded_mask = _pad(clouds, max(config.max_points, config.full_points))
    return CloudSet(padded, padded_mask, np.asarray(label, np.int32), np.full(len(clouds), SOURCES.index("scene"),
                    np.int32), np.asarray(instance, np.int32), np.asarray(yaw, np.float32))


def _make_part(path: Path, what: tuple[str, int, int], object_set: ObjectSet | tuple[str, ...],
               models_split: Literal["train", "test"], object_set_config: ObjectSetConfig, config: CloudConfig,
               perception: PerceptionConfig) -> Path:
    """Make and write one cloud file: ``what`` = ("instance", index in the split, seed) or ("scene", index, seed).
    In a worker process ``object_set`` is the split's instance names: the set is made again from
    ``object_set_config`` (its instances cached on disk) and must have them."""
    if not isinstance(object_set, ObjectSet):
        from jaxcls.world.objects import object_set_from_config

        names, object_set = object_set, object_set_from_config(object_set_config)
        if tuple(m.name for m in object_set.split(models_split)) != names:
            raise ValueError(f"clouds: data.workers > 1 remakes the object set from its config in each worker, and "
                             f"it does not give the set's {models_split} instances (an object set made in code: "
                             "data.workers=1)")
    kind, index, part_seed = what
    if kind == "instance":
        models = object_set.split(models_split)
        model = models[index]
        part = instance_clouds(model, models, object_set.class_index(model.class_name), object_set_config, config,
                               part_seed, perception)
    else:
        part = scene_clouds(object_set, models_split, object_set_config, config, part_seed, perception)
    _save_part(path, part)
    return path


def _save_part(path: Path, part: CloudSet) -> None:
    with io.atomic_write(path) as out:
        np.savez_compressed(out, points16=part.points.astype(np.float16),
                                **{f.name: getattr(part, f.name) for f in dataclasses.fields(CloudSet)
                               if f.name != "points"})


def _load_part(path: Path) -> CloudSet:
    with np.load(path) as data:
        return CloudSet(points=data["points16"].astype(np.float32),
                        **{f.name: data[f.name] for f in dataclasses.fields(CloudSet) if f.name != "points"})


_SCENE_FIELDS = ("scenes", "scene_max_views", "scene_purity", "scene_touching", "scene_noisy")


def _cache_key(object_set: ObjectSet, split: str, config: CloudConfig, object_set_config: ObjectSetConfig,
               seed: int, perception: PerceptionConfig) -> str:
    """The per-instance clouds' key (the scene source's settings are not in it: it has its own folder)."""
    defining = {**{k: v for k, v in dataclasses.asdict(config).items() if k not in _SCENE_FIELDS},
                "backend": None, "cache_dir": None, "workers": None,
                "objects": {  # clutter never stands in the clouds' scenes
                    k: v for k, v in dataclasses.asdict(object_set_config).items() if k != "clutter_source"},
                "object_set": object_set.name, "classes": object_set.classes, "split": split,
        "seed": seed, "foreground": dataclasses.asdict(perception.foreground),
        "volume": dataclasses.asdict(perception.volume), "table_height": _SCENE.table_height,
        "version": _CACHE_VERSION}
    digest = hashlib.sha1(json.dumps(defining, sort_keys=True).encode())
    for model in object_set.split(split):  # the instances themselves: a changed mesh file is a new cache
        digest.update(model.name.encode())
        digest.update(np.ascontiguousarray(model.surface_points).tobytes())
    return digest.hexdigest()[:12]


def load_clouds(object_set: ObjectSet, split: Literal["train", "test"], config: CloudConfig,
                object_set_config: ObjectSetConfig, seed: int = 0, show_progress: bool = True,
                perception: PerceptionConfig | None = None,
                models_split: Literal["train", "test"] | None = None) -> CloudSet:
    """All clouds of a split's instances, generated once and cached per instance under ``cache_dir``.

    ``split`` picks the random draw (views, poses, scenes); ``models_split`` the instances they show (default:
    the same split). ``split="test", models_split="train"`` gives held-out views and poses of the training
    instances: the evaluation of a set with one model per class (a BOP set such as LINEMOD).

    The cache folder is named by a hash of everything that defines the clouds (config, class list, the
    instances' names and surface samples; not the backend, whose renders agree), so a changed config or
    object set never reads stale clouds; an interrupted run resumes. ``config.workers`` processes make the
    missing files (each file's clouds seeded by its own index: the same clouds whatever the count).
    """
    models_split = models_split or split
    models = object_set.split(models_split)
    if not models:
        hint = "; hold some out with objects.test_fraction" if models_split == "test" else ""
        raise ValueError(f"clouds: object set '{object_set.name}' has no '{models_split}' instances{hint}")
    perception = perception or PerceptionConfig()
    key = _cache_key(object_set, models_split, config, object_set_config, seed, perception)
    name = split if models_split == split else f"{split}-views-of-{models_split}"
    folder = Path(config.cache_dir) / f"{object_set.name}_{name}_{key}"
    folder.mkdir(parents=True, exist_ok=True)
    split_id = 0 if split == "train" else 1
    instance_work = (config.full_per_instance + config.views_per_instance + config.occluded_per_instance
                     + config.fused_per_instance) > 0
    # Each cloud file, the call that makes it (``_make_part``) and its seed: instances, then scenes.
    files: list[tuple[Path, tuple]] = []
    for i, model in enumerate(models if instance_work else ()):
        seq = np.random.SeedSequence([seed, split_id, i])
        files.append((folder / f"{i:04d}_{model.name}.npz", ("instance", i, int(seq.generate_state(1)[0]))))
    if config.scenes:
        # One file per scene (scene i has its own seed: more scenes extend the cache), in a folder keyed by
        # what defines scene clouds (perception included: they are observe's segments), so a changed
        # segmentation never reads stale clouds.
        scene_defining = {**{name: getattr(config, name) for name in _SCENE_FIELDS if name != "scenes"},
                          "max_points": config.max_points,
                          "min_points": config.min_points, "image_scale": config.image_scale,
                          "perception": dataclasses.asdict(perception)}
        scene_folder = folder / ("scenes_" + hashlib.sha1(json.dumps(scene_defining, sort_keys=True).encode())
                                 .hexdigest()[:12])
        scene_folder.mkdir(exist_ok=True)
        for i in range(config.scenes):
            seq = np.random.SeedSequence([seed, split_id, 1_000_000 + i])
            files.append((scene_folder / f"scene_{i:04d}.npz", ("scene", i, int(seq.generate_state(1)[0]))))
    missing = [(path, what) for path, what in files if not path.is_file()]
    with tqdm(total=len(missing), desc=f"{split} clouds", disable=not show_progress or not missing,
              leave=False) as bar:
        # Workers get the split's instance names (the set made again from its config) and the CPU renderer
        # (renders agree); here, the set and the config themselves.
        given, made_with = ((tuple(m.name for m in models), dataclasses.replace(config, backend=Backend.mujoco))
                            if parallel.pooled(config.workers, len(missing)) else (object_set, config))
        parallel.run(_make_part, [(path, what, given, models_split, object_set_config, made_with, perception)
                                  for path, what in missing], config.workers, lambda _: bar.update())
    parts = [_load_part(path) for path, _ in files]
    parts = [dataclasses.replace(part, instance=np.full(len(part), what[1], np.int32)) if what[0] == "instance"
             else part for part, (_, what) in zip(parts, files, strict=True)]
    return CloudSet.concatenate(parts)


def sample_batch(key: jax.Array, points: jax.Array, mask: jax.Array, index: jax.Array, num_points: int,
                 rotate: bool | jax.Array = True) -> tuple[jax.Array, jax.Array]:
    """Clouds ``index: [B]`` of a bank (``points: [C, S, 3]``, ``mask: [C, S]``), each a random subset of
    ``num_points`` real points (fewer where the cloud has fewer, padded) turned by a random yaw (``rotate``
    True), by the given yaws (``rotate``: [B] rad) or not at all (False).

    Returns (points [B, num_points, 3], mask [B, num_points]). Pure JAX (runs inside the training jit).
    """
    k_sub, k_yaw = jax.random.split(key)
    pts, m = points[index], mask[index]
    priority = jnp.where(m, jax.random.uniform(k_sub, m.shape), 2.0)
    order = jnp.argsort(priority, axis=-1)[:, :num_points]
    pts = jnp.take_along_axis(pts, order[..., None], axis=1)
    m = jnp.take_along_axis(m, order, axis=1)
    if rotate is True:
        rotate = jax.random.uniform(k_yaw, index.shape, minval=-jnp.pi, maxval=jnp.pi)
    if rotate is not False:
        pts = jnp.einsum("bij,bpj->bpi", geometry.yaw_rotation(rotate), pts)
    return jnp.where(m[..., None], pts, 0.0), m
