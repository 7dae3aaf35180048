"""Cluttered table-top scenes: sampling, the MuJoCo model, and a small JSON form.

A scene is N object instances standing upright on the table (z = table height) with a random yaw, packed
close enough to occlude one another but never interpenetrating: each new object is slid in from a random
direction until the convex hulls of the footprints keep a gap drawn from ``[min_gap, max_gap]``. Upright
objects whose footprint hulls are disjoint cannot touch in 3D.

The MuJoCo model follows the contract the renderers rely on: bodies ``object_0 .. object_{N-1}`` hold the
object meshes, a box geom ``table`` has its top face at the table height, and a mocap body ``camera``
carries the depth camera ``depth`` (Kinect v1 by default), so that each element of a batch can set its
own camera pose through ``mocap_pos`` / ``mocap_quat``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from jaxcls import geometry, io
from jaxcls.config import bounded, check_bounds
from jaxcls.world.objects import ObjectModel, ObjectSet, ObjectSetConfig, object_set_from_config

if TYPE_CHECKING:
    import mujoco

SCENE_FORMAT = "jaxcls-scene"
SCENE_VERSION = 1


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """How scenes are drawn. Gaps are between footprint hulls, metres."""

    num_objects: int = bounded(5, ge=1)
    num_clutter: int = bounded(0, ge=0)  # of which non-target clutter (the paper's real scenes: 3 targets + 2)
    split: Literal["train", "test", "all"] = "test"
    # True: no instance twice, and no class twice while there are enough classes; False: instances are
    # drawn with replacement (an instance may stand on the table twice).
    distinct_classes: bool = True
    min_gap: float = bounded(0.003, gt=0.0)
    max_gap: float = bounded(0.03, gt=0.0)
    table_height: float = bounded(0.0)  # finite
    table_half_size: float = bounded(0.75, gt=0.0)

    def __post_init__(self) -> None:
        check_bounds(self, "scene.")
        if self.num_clutter > self.num_objects:
            raise ValueError(f"scene.num_clutter ({self.num_clutter}) must be <= scene.num_objects "
                             f"({self.num_objects}): clutter objects are counted among the objects")
        if self.min_gap > self.max_gap:
            raise ValueError(f"scene.min_gap ({self.min_gap}) must be <= scene.max_gap ({self.max_gap})")


@dataclasses.dataclass(frozen=True)
class PlacedObject:
    """One instance on the table: its footprint centre in world xy, its yaw about z (rad)."""

    name: str
    class_name: str
    position: tuple[float, float]
    yaw: float
    target: bool = True


@dataclasses.dataclass(frozen=True)
class Scene:
    """A scene's description; the meshes come from ``object_set`` by instance name."""

    objects: tuple[PlacedObject, ...]
    object_set: ObjectSetConfig
    table_height: float = 0.0
    table_half_size: float = 0.75
    seed: int | None = None

    @property
    def num_objects(self) -> int:
        return len(self.objects)

    def object_poses(self) -> np.ndarray:
        """[N, 4, 4] model-to-world transforms."""
        return np.stack([_pose(o.position, o.yaw, self.table_height) for o in self.objects])

    def posed_surfaces(self, models: Sequence[ObjectModel]) -> tuple[np.ndarray, ...]:
        """Each object's surface samples (``ObjectModel.surface_points``) placed in the world: [S_k, 3] f64 m,
        ``models`` in scene order (``scene_models``)."""
        return tuple(np.asarray(m.surface_points, np.float64) @ T[:3, :3].T + T[:3, 3]
                     for m, T in zip(models, self.object_poses(), strict=True))

    def to_dict(self) -> dict:
        return {
            "format": SCENE_FORMAT,
            "version": SCENE_VERSION,
            "seed": self.seed,
            "object_set": dataclasses.asdict(self.object_set),
            "table_height": self.table_height,
            "table_half_size": self.table_half_size,
            "objects": [
                {"name": o.name, "class": o.class_name, "position": list(o.position), "yaw": o.yaw,
                 "target": o.target}
                for o in self.objects
            ],
        }

    @classmethod
    def from_dict(cls, data: dict, source: str = "scene") -> Scene:
        """Inverse of ``to_dict``; errors name ``source`` (the file) and the key."""
        def need(d: dict, key: str, where: str = ""):
            if not isinstance(d, dict) or key not in d:
                raise ValueError(f"{source}: missing key '{where}{key}'")
            return d[key]

        def number(value, key: str) -> float:
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ValueError(f"{source}: key '{key}' must be a finite number, got {value!r}")
            return float(value)

        if data.get("format") != SCENE_FORMAT:
            raise ValueError(f"{source}: key 'format' must be '{SCENE_FORMAT}', got {data.get('format')!r}")
        if data.get("version") != SCENE_VERSION:
            raise ValueError(f"{source}: key 'version' must be {SCENE_VERSION}, got {data.get('version')!r}")
        seed = data.get("seed")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
            raise ValueError(f"{source}: key 'seed' must be an integer or null, got {seed!r}")
        objects = []
        for i, o in enumerate(need(data, "objects")):
            at = f"objects[{i}]."
            position = need(o, "position", at)
            if not isinstance(position, list) or len(position) != 2:
                raise ValueError(f"{source}: key '{at}position' must be [x, y], got {position!r}")
            objects.append(PlacedObject(
                name=str(need(o, "name", at)), class_name=str(need(o, "class", at)),
                position=(number(position[0], at + "position"), number(position[1], at + "position")),
                yaw=number(need(o, "yaw", at), at + "yaw"), target=bool(o.get("target", True))))
        try:
            object_set = ObjectSetConfig(**need(data, "object_set"))
        except TypeError as e:
            raise ValueError(f"{source}: key 'object_set': {e}") from None
        return cls(objects=tuple(objects), object_set=object_set,
                   table_height=number(data.get("table_height", 0.0), "table_height"),
                   table_half_size=number(data.get("table_half_size", 0.75), "table_half_size"), seed=seed)

    def save(self, path: str | Path) -> Path:
        """Write the scene's JSON to ``path`` atomically (``Scene.load`` reads it back)."""
        return io.write_text(path, json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> Scene:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: scene file not found")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise ValueError(f"{path}: not valid JSON: {e}") from None
        return cls.from_dict(data, source=str(path))


def _pose(position, yaw: float, z: float) -> np.ndarray:
    """[4, 4] float64 pose of an object standing at ``position`` (x, y) and height ``z``, turned by ``yaw``."""
    T = np.eye(4)
    T[:3, :3] = geometry.yaw_matrix_np(yaw)
    T[:3, 3] = [position[0], position[1], z]
    return T


def _place_footprint(hull: np.ndarray, position: np.ndarray, yaw: float) -> np.ndarray:
    """``hull: [K, 2]`` (object frame) turned by ``yaw`` and moved to ``position`` (x, y)."""
    return hull @ geometry.yaw_matrix_np(yaw)[:2, :2].T + position


def footprint_separation(a: np.ndarray, b: np.ndarray) -> float:
    """Separating-axis gap between convex polygons ``a: [K, 2]`` and ``b: [L, 2]`` (CCW), metres.

    Positive: disjoint, and the Euclidean distance is at least this; <= 0: they overlap.
    """
    best = -np.inf
    for p, q in ((a, b), (b, a)):
        edges = np.roll(p, -1, axis=0) - p
        normals = np.stack([edges[:, 1], -edges[:, 0]], axis=-1)
        normals /= np.linalg.norm(normals, axis=-1, keepdims=True) + 1e-12
        gap = (q @ normals.T).min(axis=0) - np.einsum("kd,kd->k", p, normals)
        best = max(best, float(gap.max()))
    return best


def sample_scene(object_set: ObjectSet, config: SceneConfig, seed: int,
                 object_set_config: ObjectSetConfig | None = None) -> Scene:
    """Draw a cluttered scene from ``object_set`` (same seed, same scene).

    With ``config.distinct_classes`` (the default) no instance appears twice, so ``num_objects`` may not
    exceed the instances of ``config.split``: that is an error naming the fixes, never a silent repeat.
    """
    rng = np.random.default_rng(seed)
    pool = object_set.split(config.split)
    if not pool:
        raise ValueError(f"scene: object set '{object_set.name}' has no '{config.split}' instances; set "
                         "scene.split=all, or hold some out with objects.test_fraction")
    if config.distinct_classes and config.num_objects > len(pool):
        more = {"test": "more held-out instances per class (objects.test_per_class for the builtin set, "
                        "objects.test_fraction for your own models)",
                "train": "more training instances per class (objects.train_per_class for the builtin set)",
                "all": "more instances per class"}[config.split]
        fixes = ["lower scene.num_objects", *(["draw from every instance with scene.split=all"]
                                              if config.split != "all" else []), more,
                 "or set scene.distinct_classes=false if repeated instances are wanted"]
        raise ValueError(f"scene.num_objects = {config.num_objects}, but object set '{object_set.name}' has "
                         f"{len(pool)} instances in split '{config.split}' and scene.distinct_classes=true never "
                         f"draws an instance twice: {', '.join(fixes)}")
    if object_set.clutter and config.num_clutter:  # clutter from its own set (ObjectSetConfig.clutter_source)
        targets = config.num_objects - config.num_clutter
        if config.distinct_classes and config.num_clutter > len(object_set.clutter):
            raise ValueError(f"scene.num_clutter = {config.num_clutter}, but the clutter set has "
                             f"{len(object_set.clutter)} instances; lower scene.num_clutter or set "
                             "scene.distinct_classes=false")
        models = (_draw_instances(rng, pool, targets, config.distinct_classes)
                  + _draw_instances(rng, object_set.clutter, config.num_clutter, config.distinct_classes))
    else:
        models = _draw_instances(rng, pool, config.num_objects, config.distinct_classes)
    return _arrange(models, config, rng, object_set_config, seed)


def arrange_scene(models: Sequence[ObjectModel], config: SceneConfig, seed: int,
                  object_set_config: ObjectSetConfig | None = None) -> Scene:
    """A scene of exactly ``models`` (in random order), placed as ``sample_scene`` places its draw."""
    if not models:
        raise ValueError("arrange_scene: need at least one model")
    config = dataclasses.replace(config, num_objects=len(models), num_clutter=min(config.num_clutter, len(models)))
    return _arrange(list(models), config, np.random.default_rng(seed), object_set_config, seed)


def _arrange(models: list[ObjectModel], config: SceneConfig, rng: np.random.Generator,
             object_set_config: ObjectSetConfig | None, seed: int) -> Scene:
    hulls: list[np.ndarray] = []
    placed: list[PlacedObject] = []
    for i, model in enumerate(models):
        yaw = float(rng.uniform(-math.pi, math.pi))
        hull = model.footprint()
        if not hulls:
            position = np.zeros(2)
        else:
            gap = rng.uniform(config.min_gap, config.max_gap)
            anchor = np.mean([h.mean(axis=0) for h in hulls], axis=0)
            position = _slide_in(hull, yaw, hulls, anchor, rng.uniform(0, 2 * math.pi), gap)
        hulls.append(_place_footprint(hull, position, yaw))
        placed.append(PlacedObject(name=model.name, class_name=model.class_name,
                                   position=(float(position[0]), float(position[1])), yaw=yaw,
                                   target=i < config.num_objects - config.num_clutter))
    # Centre the cluster on the table origin.
    shift = -np.mean([h.mean(axis=0) for h in hulls], axis=0)
    placed = [dataclasses.replace(o, position=(o.position[0] + shift[0], o.position[1] + shift[1]))
              for o in placed]
    reach = max(float(np.abs(h + shift).max()) for h in hulls)
    if reach > config.table_half_size:
        raise ValueError(f"scene: the objects reach {reach:.3f} m from the table centre, beyond "
                         f"table_half_size = {config.table_half_size} m")
    order = rng.permutation(len(placed))  # clutter is not always drawn last
    return Scene(objects=tuple(placed[k] for k in order),
                 object_set=object_set_config or ObjectSetConfig(), table_height=config.table_height,
                 table_half_size=config.table_half_size, seed=seed)


def _draw_instances(rng: np.random.Generator, pool, count: int, distinct: bool) -> list[ObjectModel]:
    """``count`` instances of ``pool``.

    distinct: no instance twice; classes are distinct while ``count`` <= the number of classes, beyond
    that every class comes once and the rest are other instances (needs ``count <= len(pool)``). Not
    distinct: instances drawn with replacement.
    """
    if not distinct:
        return [pool[k] for k in rng.integers(len(pool), size=count)]
    if count > len(pool):
        raise ValueError(f"scene: {count} distinct instances asked of a pool of {len(pool)}")
    classes = sorted({m.class_name for m in pool})
    by_class = {c: [m for m in pool if m.class_name == c] for c in classes}
    chosen = rng.choice(len(classes), size=min(count, len(classes)), replace=False)
    picked = [by_class[classes[k]][rng.integers(len(by_class[classes[k]]))] for k in chosen]
    if count > len(picked):  # more objects than classes: fill with other instances, none twice
        rest = [m for m in pool if all(m is not p for p in picked)]
        picked += [rest[k] for k in rng.choice(len(rest), size=count - len(picked), replace=False)]
    return picked


def _slide_in(hull: np.ndarray, yaw: float, placed: list[np.ndarray], anchor: np.ndarray,
              direction: float, gap: float, step: float = 0.002) -> np.ndarray:
    """Bring a footprint from ``anchor`` outwards along ``direction`` in steps of ``step`` until it clears every
    hull by ``gap``: the first step that does.

    The separation is 1-Lipschitz in the footprint's position (a maximum over axes of gaps that each move by at
    most the distance moved), so a step whose separation falls short by s leaves at least s / step - 1 steps
    that cannot clear; those are counted (``t`` accumulates exactly as one step at a time) without testing."""
    d = np.array([math.cos(direction), math.sin(direction)])
    t = 0.0
    while True:
        position = anchor + t * d
        moved = _place_footprint(hull, position, yaw)
        short = gap - min(footprint_separation(moved, h) for h in placed)
        if short <= 0:
            return position
        for _ in range(max(1, int(short / step))):  # the last one skipped is tested: a step's margin
            t += step


def scene_models(scene: Scene, object_set: ObjectSet | None = None) -> tuple[ObjectModel, ...]:
    """The object models of ``scene`` in scene order, from ``object_set`` or the one its JSON names."""
    object_set = object_set or object_set_from_config(scene.object_set)
    by_name = {m.name: m for m in object_set.split("all") + object_set.clutter}
    missing = [o.name for o in scene.objects if o.name not in by_name]
    if missing:
        raise ValueError(f"scene: instances {missing} are not in object set '{object_set.name}'")
    return tuple(by_name[o.name] for o in scene.objects)


def scene_centroid(scene: Scene, models: tuple[ObjectModel, ...]) -> np.ndarray:
    """[3] mean of the objects' bounding-cuboid centres in the world: the centre of the view hemisphere."""
    centres = [T[:3, :3] @ model.bounds.mean(axis=0) + T[:3, 3]
               for model, T in zip(models, scene.object_poses(), strict=True)]
    return np.mean(centres, axis=0)


def viewpoints(scene: Scene, models: tuple[ObjectModel, ...], config: geometry.ViewpointConfig) -> np.ndarray:
    """[V, 4, 4] ``T_wc`` of the scene's view hemisphere, centred on ``scene_centroid``."""
    return geometry.hemisphere_viewpoints(scene_centroid(scene, models), config.count, config.radius,
                                          config.min_elevation_deg)


def build_model(scene: Scene, models: tuple[ObjectModel, ...] | None = None,
                intrinsics: geometry.Intrinsics | None = None) -> mujoco.MjModel:
    """The MuJoCo model of ``scene`` with the depth camera on a mocap body (see the module docstring)."""
    models = models if models is not None else scene_models(scene)
    bodies = [(model, f"mesh_{i}", _pose(obj.position, obj.yaw, scene.table_height))
              for i, (obj, model) in enumerate(zip(scene.objects, models, strict=True))]
    return compile_model(bodies, scene.table_height, scene.table_half_size, intrinsics)


def compile_model(bodies: Sequence[tuple[ObjectModel, str, np.ndarray]], table_height: float, table_half_size: float,
                  intrinsics: geometry.Intrinsics | None = None, mocap: bool = False) -> mujoco.MjModel:
    """A MuJoCo model under the render contract: the table, the depth camera on its mocap body, and body
    ``object_<i>`` for each (model, mesh name, pose [4, 4]) of ``bodies`` (bodies naming the same mesh share
    it); ``mocap``: the object bodies are mocap bodies, their poses the rest poses given here (the scene bank's)."""
    import mujoco  # here: scene descriptions and configs load without MuJoCo

    intrinsics = intrinsics or geometry.Intrinsics.kinect_v1()
    intrinsics.validate_mujoco()
    spec = mujoco.MjSpec()
    spec.modelname = "jaxcls_scene"
    spec.add_material(name="table", rgba=[0.55, 0.45, 0.35, 1])
    spec.add_material(name="object", rgba=[0.8, 0.8, 0.8, 1])
    world = spec.worldbody
    h, half = table_height, table_half_size
    world.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=[half, half, 0.01],
                   pos=[0, 0, h - 0.01], material="table")
    world.add_light(name="top", pos=[0, 0, h + 3], dir=[0, 0, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
    meshes: set[str] = set()
    for i, (model, mesh_name, T) in enumerate(bodies):
        if mesh_name not in meshes:
            meshes.add(mesh_name)
            spec.add_mesh(name=mesh_name, uservert=model.mesh.vertices.astype(np.float32).ravel().tolist(),
                          userface=model.mesh.faces.astype(np.int32).ravel().tolist())
        body = world.add_body(name=f"object_{i}", pos=np.asarray(T)[:3, 3].tolist(), mocap=mocap,
                              quat=geometry.rotation_to_quat(np.asarray(T)[:3, :3]).tolist())
        body.add_geom(name=f"object_{i}", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh_name,
                      material="object")
    camera = world.add_body(name="camera", mocap=True, pos=[0, 0, h + 1])
    camera.add_camera(name="depth", fovy=intrinsics.fovy_deg, resolution=[intrinsics.width, intrinsics.height])
    try:
        return spec.compile()
    except ValueError as e:
        raise ValueError(f"scene: MuJoCo could not compile the scene model: {e}") from None


def object_distances(model: mujoco.MjModel, distmax: float = 0.1) -> np.ndarray:
    """[N, N] MuJoCo's signed distance between object geoms (C ``mj_geomDistance``); the diagonal is inf.

    Negative means interpenetration. Pairs farther than ``distmax`` read ``distmax``.
    """
    import mujoco

    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    geoms = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"object_{i}")
             for i in range(model.nbody)]
    geoms = [g for g in geoms if g >= 0]
    n = len(geoms)
    out = np.full((n, n), np.inf)
    for i in range(n):
        for j in range(i + 1, n):
            out[i, j] = out[j, i] = mujoco.mj_geomDistance(model, data, geoms[i], geoms[j], distmax, None)
    return out


def occlusion_counts(scene: Scene, models: tuple[ObjectModel, ...], intrinsics: geometry.Intrinsics,
                     T_wc: np.ndarray, backend: str = "mujoco") -> tuple[np.ndarray, np.ndarray]:
    """How much of each object the others hide: (seen [V, N], alone [V, N]) pixel counts, i32.

    ``seen``: pixels of object j in the scene seen from ``T_wc: [V, 4, 4]``; ``alone``: its pixels with
    the other objects removed (the table stays). ``seen / alone`` is the visible fraction, where alone > 0.
    """
    from jaxcls.world.render import make_renderer

    def counts(sub: Scene, sub_models: tuple[ObjectModel, ...]) -> np.ndarray:
        frames = make_renderer(build_model(sub, sub_models, intrinsics), intrinsics, backend).render(T_wc)
        ids = np.asarray(frames.object_id)
        return np.stack([(ids == j).sum(axis=(1, 2)) for j in range(sub.num_objects)], axis=-1)

    seen = counts(scene, models)
    alone = np.concatenate([counts(dataclasses.replace(scene, objects=(obj,)), (model,))
                            for obj, model in zip(scene.objects, models, strict=True)], axis=-1)
    return seen.astype(np.int32), alone.astype(np.int32)
