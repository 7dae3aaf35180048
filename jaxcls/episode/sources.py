"""Where an episode's frames come from: a ``ViewSource`` gives the viewpoints the policy chooses among and
the frame of any one of them.

- ``Preloaded``: every viewpoint's frame in memory. ``dataset_source`` reads a scene file written by
  ``jaxcls dataset`` (the paper's fixed 100 viewpoints: the loop only indexes them); ``recording_source``
  reads a recorded sequence (``world.recording``: the real-robot path, a fixed set of viewpoints with
  poses from the arm); ``bag_source`` a ROS bag (``world.rosbag``: depth images and poses from TF).
- ``Rendered``: a ``World`` asked on demand, through its sensor model (any backend); ``frame_at`` renders
  any pose, for views off the fixed set.

Each source knows the camera, the table height and, when it has one, the scene (to score the episode).

Every frame a source gives is z-depth in metres, 0 where there is no return, never NaN or negative
(docs/ARCHITECTURE.md): a ``Preloaded`` source checks its frames whole when it is made
(``world.dataset.check_views``: a depth frame per pose, the camera's size, finite depth >= 0, rigid poses)
and refuses bad ones with a ValueError naming the source (its file or folder) and the view.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Protocol

import jax
import numpy as np

from jaxcls.geometry import Intrinsics
from jaxcls.world import recording as recordings
from jaxcls.world.dataset import SceneViews, check_views
from jaxcls.world.objects import ObjectSetConfig
from jaxcls.world.rosbag import BagConfig, read_bag
from jaxcls.world.scenes import Scene
from jaxcls.world.setup import World


class ViewSource(Protocol):
    """viewpoints: [V, 4, 4] T_wc the policy chooses among; intrinsics; table_height (m); scene (or None);
    name: what it is, for messages and reports."""

    viewpoints: np.ndarray
    intrinsics: Intrinsics
    table_height: float
    scene: Scene | None
    name: str

    def frame(self, view: int) -> tuple[np.ndarray, np.ndarray]:
        """(depth [H, W] f32 m, 0 = no return; T_wc [4, 4] the pose the pipeline is given) of viewpoint ``view``."""
        ...


def _check_view(source: ViewSource, view: int) -> int:
    view = int(view)
    if not 0 <= view < len(source.viewpoints):
        raise ValueError(f"{source.name}: view {view} is outside 0..{len(source.viewpoints) - 1}")
    return view


@dataclasses.dataclass(frozen=True, eq=False)
class Preloaded:
    """Every viewpoint's frame in memory. depth: [V, H, W] f32 m; T_wc: [V, 4, 4] (also the viewpoints).
    Checked when made (``check_views``): ValueError naming ``name`` and the view."""

    depth: np.ndarray
    T_wc: np.ndarray
    intrinsics: Intrinsics
    table_height: float
    scene: Scene | None
    name: str

    def __post_init__(self) -> None:
        check_views(self.name, self.depth, self.T_wc, self.intrinsics)

    @property
    def viewpoints(self) -> np.ndarray:
        return self.T_wc

    def frame(self, view: int) -> tuple[np.ndarray, np.ndarray]:
        view = _check_view(self, view)
        return self.depth[view], self.T_wc[view]


def dataset_source(path: str | Path, objects: ObjectSetConfig | None = None, intrinsics: Intrinsics | None = None
                   ) -> Preloaded:
    """A scene file of ``jaxcls dataset`` (``scene_NNN.npz``). With ``objects`` / ``intrinsics``, a file of
    another object set or camera is refused (ValueError naming the file and what differs)."""
    path = Path(path)
    views = SceneViews.load(path)
    if objects is not None and views.scene.object_set != objects:
        raise ValueError(f"{path}: the scene was drawn from objects {views.scene.object_set}, but the run's "
                         f"objects are {objects}; render a dataset of this object set (jaxcls dataset)")
    if intrinsics is not None and views.intrinsics != intrinsics:
        raise ValueError(f"{path}: key 'intrinsics' {views.intrinsics} differs from the run's camera {intrinsics}")
    return Preloaded(depth=views.depth, T_wc=np.asarray(views.T_wc, np.float64), intrinsics=views.intrinsics,
                     table_height=views.scene.table_height, scene=views.scene, name=str(path))


def recording_source(folder: str | Path, objects: ObjectSetConfig | None = None) -> Preloaded:
    """A recorded sequence (``world.recording``'s folder format; a damaged or incomplete one is a
    ``RecordingError`` naming the file). Its frames are the viewpoints; a scene in its ``meta.json`` is read
    (to score the episode) and, with ``objects``, must be of that object set."""
    folder = Path(folder)
    rec = recordings.read_recording(folder)
    scene = None
    if rec.scene is not None:
        scene = Scene.from_dict(rec.scene, source=str(folder / "meta.json"))
        if objects is not None and scene.object_set != objects:
            raise ValueError(f"{folder / 'meta.json'}: key 'scene' was drawn from objects {scene.object_set}, but "
                             f"the run's objects are {objects}")
    return Preloaded(depth=rec.depth, T_wc=rec.T_wc, intrinsics=rec.intrinsics, table_height=rec.table_height,
                     scene=scene, name=str(folder))


def bag_source(path: str | Path, config: BagConfig | None = None) -> Preloaded:
    """A ROS bag (``world.rosbag``: depth images, CameraInfo, poses from TF or a PoseStamped topic, as
    ``config`` names them): its frames in time order are the viewpoints; no scene (nothing to score)."""
    rec = read_bag(path, config)
    return Preloaded(depth=rec.depth, T_wc=rec.T_wc, intrinsics=rec.intrinsics, table_height=rec.table_height,
                     scene=None, name=str(path))


@dataclasses.dataclass(frozen=True, eq=False)
class Rendered:
    """A world rendered on demand through its sensor model; the noise of viewpoint v is drawn from
    ``fold_in(key, v)``, so a view seen twice gives the same frame."""

    world: World
    key: jax.Array

    @property
    def viewpoints(self) -> np.ndarray:
        return self.world.viewpoints

    @property
    def intrinsics(self) -> Intrinsics:
        return self.world.intrinsics

    @property
    def table_height(self) -> float:
        return self.world.table_height

    @property
    def scene(self) -> Scene:
        return self.world.scene

    @property
    def name(self) -> str:
        return f"scene seed {self.world.scene.seed} ({self.world.backend})"

    def frame(self, view: int) -> tuple[np.ndarray, np.ndarray]:
        view = _check_view(self, view)
        depth, T_wc, _, _ = self.world.measure(jax.random.fold_in(self.key, view), [view])
        return depth[0], T_wc[0]

    def frame_at(self, T_wc: np.ndarray, key: jax.Array) -> np.ndarray:
        """Depth [H, W] f32 m seen from any pose ``T_wc: [4, 4]`` (sensor noise from ``key``; no pose noise)."""
        from jaxcls.world.render.sensor import apply_sensor

        frames = self.world.renderer.render(np.asarray(T_wc, np.float64)[None])
        return np.asarray(apply_sensor(key, np.asarray(frames.depth), self.intrinsics, self.world.config.sensor))[0]
