"""One world set-up: a world config and a seed (or a saved scene) -> the scene, its models, its viewpoints,
its MuJoCo model and a renderer. Every command, experiment, benchmark, test and notebook builds its world
here.

    world = make_world(WorldConfig(), seed=0)
    frames = world.render([0, 33])                      # ideal depth + object ids of two viewpoints
    depth, T_wc = world.measure(key, [0, 33])           # through the sensor model (noise, pose error)

``WorldConfig`` is the block every world-making command shares: its fields are the top-level keys
``objects``, ``scene``, ``camera``, ``viewpoints``, ``sensor`` and ``backend`` of ``jaxcls show`` and
``jaxcls dataset`` configs (their schemas extend it).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import TYPE_CHECKING

import jax
import numpy as np

from jaxcls import geometry
from jaxcls.world import scenes
from jaxcls.world.objects import ObjectModel, ObjectSet, ObjectSetConfig, object_set_from_config
from jaxcls.world.render.sensor import SensorConfig
from jaxcls.world.render.types import Backend

if TYPE_CHECKING:
    import mujoco

    from jaxcls.world.render.types import DepthFrames, Renderer


@dataclasses.dataclass(frozen=True)
class WorldConfig:
    """What a world is made of: object set, scene layout, camera, view hemisphere, sensor, render backend."""

    objects: ObjectSetConfig = dataclasses.field(default_factory=ObjectSetConfig)
    scene: scenes.SceneConfig = dataclasses.field(default_factory=scenes.SceneConfig)
    camera: geometry.CameraConfig = dataclasses.field(default_factory=geometry.CameraConfig)
    viewpoints: geometry.ViewpointConfig = dataclasses.field(default_factory=geometry.ViewpointConfig)
    sensor: SensorConfig = dataclasses.field(default_factory=SensorConfig.ideal)
    backend: Backend = Backend.auto

    def world_config(self) -> WorldConfig:
        """Just the world part of a command's config (whose schema extends this one)."""
        return WorldConfig(**{f.name: getattr(self, f.name) for f in dataclasses.fields(WorldConfig)})


@dataclasses.dataclass(frozen=True, eq=False)
class World:
    """A scene ready to be seen.

    scene: the placed objects (``scenes.Scene``); models: their ``ObjectModel``s in scene order;
    intrinsics: the camera; viewpoints: [V, 4, 4] ``T_wc`` of the view hemisphere around the scene;
    backend: the resolved render backend. ``model`` (MuJoCo) and ``renderer`` are built on first use.
    """

    config: WorldConfig
    object_set: ObjectSet
    scene: scenes.Scene
    models: tuple[ObjectModel, ...]
    intrinsics: geometry.Intrinsics
    viewpoints: np.ndarray
    backend: str

    @property
    def table_height(self) -> float:
        return self.scene.table_height

    @property
    def centroid(self) -> np.ndarray:
        """[3] m: the scene's centre, where the view hemisphere is centred (``scenes.scene_centroid``)."""
        return scenes.scene_centroid(self.scene, self.models)

    @functools.cached_property
    def model(self) -> mujoco.MjModel:
        """The scene's MuJoCo model (the render contract: ``world.render.contract``)."""
        return scenes.build_model(self.scene, self.models, self.intrinsics)

    @functools.cached_property
    def renderer(self) -> Renderer:
        from jaxcls.world.render import make_renderer

        return make_renderer(self.model, self.intrinsics, self.backend)

    def poses(self, views: Sequence[int] | np.ndarray) -> np.ndarray:
        """[K, 4, 4] ``T_wc`` of viewpoint indices ``views`` (errors name the bad index)."""
        views = np.atleast_1d(np.asarray(views))
        if views.dtype.kind not in "iu":
            raise ValueError(f"world: view indices must be integers, got {views.dtype}")
        bad = [int(v) for v in views if not 0 <= v < len(self.viewpoints)]
        if bad:
            raise ValueError(f"world: views {bad} are outside 0..{len(self.viewpoints) - 1} "
                             f"(viewpoints.count = {len(self.viewpoints)})")
        return self.viewpoints[views]

    def render(self, views: Sequence[int] | np.ndarray) -> DepthFrames:
        """Ideal depth [K, H, W] m and object ids [K, H, W] of viewpoint indices ``views``."""
        return self.renderer.render(self.poses(views))

    def measure(self, key: jax.Array, views: Sequence[int] | np.ndarray, batch_size: int = 50,
                progress=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the sensor delivers at ``views``: (depth [K, H, W] f32 m after the sensor model, T_wc
        [K, 4, 4] the poses the pipeline is told (hand-eye noise, if on), object_id [K, H, W] (ideal),
        T_wc_true [K, 4, 4] the poses rendered from). Rendered ``batch_size`` views at a time."""
        from jaxcls.world.render.sensor import measure

        T_true = self.poses(views)
        depth, object_id = [], []
        for start in range(0, len(T_true), batch_size):
            frames = self.renderer.render(T_true[start:start + batch_size])
            depth.append(np.asarray(frames.depth))
            object_id.append(np.asarray(frames.object_id))
            if progress is not None:
                progress.update(len(frames.depth))
        depth, T_believed = measure(key, np.concatenate(depth), T_true, self.intrinsics, self.config.sensor)
        return np.asarray(depth), T_believed, np.concatenate(object_id), T_true


def make_world(config: WorldConfig | None = None, seed: int = 0, scene: scenes.Scene | None = None,
               object_set: ObjectSet | None = None) -> World:
    """The world of ``config``: scene ``seed`` drawn from its object set, or the given ``scene`` (its JSON
    names its object set, which must agree with ``config.objects``). ``object_set`` skips loading it again.

    With a ``scene``, ``seed`` is unused and ``World.config.scene`` takes the scene's own table and object
    counts (what ``config.scene`` would otherwise have drawn), so that a saved config says what was shown.
    """
    from jaxcls.world.render import resolve_backend

    config = config or WorldConfig()
    if scene is not None and scene.object_set != config.objects:
        raise ValueError(f"world: the scene was drawn from objects {scene.object_set} but the config names "
                         f"{config.objects}; drop the objects.* settings or the scene file")
    object_set = object_set or object_set_from_config(config.objects)
    if scene is None:
        scene = scenes.sample_scene(object_set, config.scene, seed, config.objects)
    else:
        config = dataclasses.replace(config, scene=dataclasses.replace(
            config.scene, num_objects=scene.num_objects, num_clutter=sum(not o.target for o in scene.objects),
            table_height=scene.table_height, table_half_size=scene.table_half_size))
    models = scenes.scene_models(scene, object_set)
    return World(config=config, object_set=object_set, scene=scene, models=models,
                 intrinsics=config.camera.intrinsics(), viewpoints=scenes.viewpoints(scene, models, config.viewpoints),
                 backend=resolve_backend(config.backend))
