"""Viewpoint datasets: scenes x every hemisphere viewpoint, rendered to compressed arrays on disk.

Layout of a dataset folder::

    <out_dir>/
      config.yaml          the resolved DatasetConfig that made it
      scene_000.npz        one file per scene, written atomically (see SceneViews for its arrays)
      scene_001.npz
      ...

A run that is interrupted resumes: finished scene files are kept, a half-written one never exists (each is
written to a temporary name and renamed), and a folder made by a different config is refused rather than
mixed.

A scene file is checked whole when it is read (``SceneViews.load``, ``check_views``): one depth frame, object
id map and pose per view, frames of the camera's size, rigid finite poses, depth finite and >= 0 (0 = no
return), object ids of the scene's objects; a file that breaks a rule is refused with a ValueError naming
the file and the first view at fault, not met as an IndexError or a NaN moves later.
"""

from __future__ import annotations

import dataclasses
import json
import warnings
import zipfile
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxcls import geometry, io, parallel
from jaxcls.config import bounded, check_bounds, load_config, save_config
from jaxcls.world import recording, scenes
from jaxcls.world.objects import object_set_from_config
from jaxcls.world.render import Backend, resolve_backend
from jaxcls.world.setup import WorldConfig, make_world


@dataclasses.dataclass(frozen=True)
class DatasetConfig(WorldConfig):
    """``jaxcls dataset``: the world (``WorldConfig``: objects, scene, camera, viewpoints, sensor, backend),
    how many scenes, where to."""

    name: str = "synthetic"
    out_dir: str = "data/synthetic"
    num_scenes: int = bounded(7, ge=1)
    seed: int = bounded(0, ge=0, lt=2**32)  # the scenes drawn and the sensor's noise (a 32-bit unsigned integer)
    batch_size: int = bounded(50, ge=1)  # views rendered together
    # Scenes rendered at once, each in its own process on the CPU (the MuJoCo renderer is single-threaded;
    # the worker processes keep JAX on the CPU). 1 renders in this process.
    workers: int = bounded(1, ge=1)

    def __post_init__(self) -> None:
        check_bounds(self, "")

    def output_defining(self) -> DatasetConfig:
        """This config without the fields that do not change what is written (where, how many at once)."""
        return dataclasses.replace(self, out_dir="", batch_size=1, workers=1)


@dataclasses.dataclass(frozen=True)
class SceneViews:
    """One scene seen from every viewpoint.

    depth: [V, H, W] f32 metres, 0 = no return (after the sensor model, if on)
    object_id: [V, H, W] i16 index into ``scene.objects``, -1 = table or nothing (ideal, before noise)
    T_wc: [V, 4, 4] the camera poses the pipeline is given (with hand-eye noise, if on)
    T_wc_true: [V, 4, 4] the poses the frames were rendered from
    backend: the renderer that made the frames (backends agree within 1 mm, not bit for bit)
    """

    scene: scenes.Scene
    intrinsics: geometry.Intrinsics
    depth: np.ndarray
    object_id: np.ndarray
    T_wc: np.ndarray
    T_wc_true: np.ndarray
    backend: str = "mujoco"

    def save(self, path: str | Path) -> Path:
        """Write atomically (``io.atomic_write``): never a partial file."""
        intr = self.intrinsics
        with io.atomic_write(path) as f:
            np.savez_compressed(
                f, depth=self.depth.astype(np.float32), object_id=self.object_id.astype(np.int16),
                T_wc=self.T_wc, T_wc_true=self.T_wc_true,
                intrinsics=np.array([intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy]),
                scene_json=np.array(json.dumps(self.scene.to_dict())), backend=np.array(self.backend))
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> SceneViews:
        """Read a scene file and check it whole (``check_views``); ValueError naming the file (and view)."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: scene views file not found")
        keys = ("depth", "object_id", "T_wc", "T_wc_true", "intrinsics", "scene_json")
        try:
            with np.load(path, allow_pickle=False) as f:
                arrays = {k: f[k] for k in (*keys, "backend") if k in f}
        except (OSError, EOFError, ValueError, zipfile.BadZipFile) as e:
            raise ValueError(f"{path}: not a readable scene views file ({type(e).__name__}: {e})") from None
        missing = [k for k in keys if k not in arrays]
        if missing:
            raise ValueError(f"{path}: missing arrays {missing}")
        if arrays["intrinsics"].shape != (6,):
            raise ValueError(f"{path}: 'intrinsics' must hold 6 numbers (width, height, fx, fy, cx, cy), got shape "
                             f"{arrays['intrinsics'].shape}")
        w, h, fx, fy, cx, cy = arrays["intrinsics"].tolist()
        try:
            intrinsics = geometry.Intrinsics(width=int(w), height=int(h), fx=fx, fy=fy, cx=cx, cy=cy)
        except (ValueError, OverflowError) as e:
            raise ValueError(f"{path}: 'intrinsics': {e}") from None
        scene = scenes.Scene.from_dict(json.loads(str(arrays["scene_json"])), source=str(path))
        check_views(str(path), arrays["depth"], arrays["T_wc"], intrinsics, object_id=arrays["object_id"],
                    T_wc_true=arrays["T_wc_true"], num_objects=scene.num_objects)
        return cls(scene=scene, intrinsics=intrinsics, depth=arrays["depth"],
                   object_id=arrays["object_id"].astype(np.int32), T_wc=arrays["T_wc"], T_wc_true=arrays["T_wc_true"],
                   backend=str(arrays.get("backend", "unknown")))

    def to_recording(self) -> recording.Recording:
        """The recorded-sequence form a real sensor would produce (depth rounded to millimetres)."""
        return recording.Recording(depth=self.depth, T_wc=self.T_wc, intrinsics=self.intrinsics,
                                   table_height=self.scene.table_height, scene=self.scene.to_dict())


def _views(mask: np.ndarray) -> str:
    """The views flagged in ``mask: [V]`` bool, for a message: "view 3" or "views 3, 7, 9, ... (12 views)"."""
    views = np.flatnonzero(mask).tolist()
    if len(views) == 1:
        return f"view {views[0]}"
    listed = ", ".join(map(str, views[:3])) + (", ..." if len(views) > 3 else "")
    return f"views {listed} ({len(views)} views)"


def check_views(where: str, depth: np.ndarray, T_wc: np.ndarray, intrinsics: geometry.Intrinsics, *,
                object_id: np.ndarray | None = None, T_wc_true: np.ndarray | None = None,
                num_objects: int | None = None) -> None:
    """Refuse frames that a run cannot use, with a ValueError naming ``where`` (the file) and the view.

    depth: [V, H, W] z-depth in metres of ``intrinsics``' size, finite and >= 0 (0 = no return; a NaN,
    inf or negative pixel is refused: a writer that means "no return" writes 0); T_wc: [V, 4, 4] rigid,
    one pose per depth frame; object_id: [V, H, W] in -1..num_objects-1; T_wc_true: like T_wc.
    """
    depth, T_wc = np.asarray(depth), np.asarray(T_wc)
    if depth.ndim != 3:
        raise ValueError(f"{where}: 'depth' must be [V, H, W] (a frame per view), got shape {depth.shape}")
    hw = (intrinsics.height, intrinsics.width)
    if depth.shape[1:] != hw:
        raise ValueError(f"{where}: 'depth' frames are {depth.shape[1]}x{depth.shape[2]} (H x W), the camera "
                         f"('intrinsics') is {hw[0]}x{hw[1]}")
    if T_wc.ndim != 3 or T_wc.shape[1:] != (4, 4):
        raise ValueError(f"{where}: 'T_wc' must be [V, 4, 4] (a pose per view), got shape {T_wc.shape}")
    frames, poses = len(depth), len(T_wc)
    if frames != poses:
        lo, hi = min(frames, poses), max(frames, poses)
        views = f"view {lo} has" if hi - lo == 1 else f"views {lo}..{hi - 1} have"
        raise ValueError(f"{where}: 'depth' has {frames} frames but 'T_wc' has {poses} poses: {views} no "
                         f"{'depth frame' if frames < poses else 'pose'}")
    for name, array, shape in (("object_id", object_id, depth.shape), ("T_wc_true", T_wc_true, T_wc.shape)):
        if array is not None and np.shape(array) != shape:
            raise ValueError(f"{where}: '{name}' has shape {np.shape(array)}, expected {shape} like "
                             f"'{'depth' if name == 'object_id' else 'T_wc'}'")
    for name, array in (("T_wc", T_wc), ("T_wc_true", T_wc_true)):
        if array is not None and not (rigid := geometry.is_rigid(array)).all():
            raise ValueError(f"{where}: {_views(~rigid)}: pose '{name}' is not a rigid transform (finite, rotation "
                             "with det +1, last row 0 0 0 1)")
    if not np.issubdtype(depth.dtype, np.floating):
        raise ValueError(f"{where}: 'depth' must be floating-point metres, got dtype {depth.dtype}")
    for what, bad in (("NaN or infinite", ~np.isfinite(depth)), ("negative", depth < 0)):
        per_view = bad.sum(axis=(1, 2))
        if per_view.any():
            first = int(np.flatnonzero(per_view)[0])
            raise ValueError(f"{where}: {_views(per_view > 0)}: 'depth' has {what} pixels ({int(per_view[first])} in "
                             f"view {first}); depth is z-depth in metres, 0 where there is no return")
    if object_id is not None and num_objects is not None:
        ids = np.asarray(object_id)
        wrong = ((ids < -1) | (ids >= num_objects)).any(axis=(1, 2))
        if wrong.any():
            raise ValueError(f"{where}: {_views(wrong)}: 'object_id' holds ids outside -1..{num_objects - 1} "
                             f"(the scene has {num_objects} objects; -1 = table or nothing)")


def scene_seeds(seed: int, count: int) -> list[int]:
    """Independent per-scene seeds, stable under a change of ``count``."""
    return [int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(count)]


def scene_key(seed: int, index: int) -> jax.Array:
    """The sensor-noise key of scene ``index`` of a dataset with ``seed`` (its frames' noise draw)."""
    return jax.random.fold_in(jax.random.PRNGKey(seed), index)


def scene_file(out_dir: str | Path, index: int) -> Path:
    return Path(out_dir) / f"scene_{index:03d}.npz"


def render_scene_views(config: DatasetConfig, scene: scenes.Scene, key: jax.Array,
                       object_set=None, progress: tqdm | None = None) -> SceneViews:
    """Render ``scene`` from every viewpoint of ``config`` and apply its sensor model."""
    world = make_world(config.world_config(), scene=scene, object_set=object_set)
    depth, T_believed, object_id, T_true = world.measure(key, np.arange(len(world.viewpoints)), config.batch_size,
                                                         progress)
    return SceneViews(scene=scene, intrinsics=world.intrinsics, depth=depth, object_id=object_id,
                      T_wc=T_believed, T_wc_true=T_true, backend=world.backend)


def build_dataset(config: DatasetConfig, overwrite: bool = False, show_progress: bool = True) -> Path:
    """Render ``config.num_scenes`` scenes x all viewpoints into ``config.out_dir``; resumes if interrupted."""
    out = Path(config.out_dir)
    io.check_out_dir(out)  # before anything is rendered: a file, or a folder that cannot be written
    config_file = out / "config.yaml"
    if config_file.exists() and not overwrite:
        previous = load_config(DatasetConfig, config_file)
        if previous.output_defining() != config.output_defining():
            raise ValueError(f"{config_file}: this folder holds a dataset made by a different config; "
                             "choose another out_dir or pass --overwrite")
    out.mkdir(parents=True, exist_ok=True)
    if overwrite:
        for stale in out.glob("scene_*.npz"):
            stale.unlink()
    save_config(config, config_file)
    object_set = object_set_from_config(config.objects)
    todo = [i for i in range(config.num_scenes) if not _finished(scene_file(out, i))]
    with tqdm(total=len(todo) * config.viewpoints.count, desc=f"dataset {config.name}", unit="view",
              disable=not show_progress) as bar:
        if not parallel.pooled(config.workers, len(todo)):  # here, the bar moving view by view
            for i in todo:
                bar.set_postfix(scene=i)
                _render_scene(config, i, object_set, bar)
            return out
        if resolve_backend(config.backend) is not Backend.mujoco:
            raise ValueError(f"workers={config.workers}: scenes render in parallel with the CPU renderer only; "
                             f"set backend=mujoco (backend={config.backend!r} resolves to "
                             f"{resolve_backend(config.backend)!r}) or workers=1")
        config = dataclasses.replace(config, backend="mujoco")

        def rendered(index: int) -> None:
            bar.set_postfix(scene=index)
            bar.update(config.viewpoints.count)

        # Each worker renders and writes whole scenes.
        parallel.run(_render_scene, [(config, i) for i in todo], config.workers, rendered)
    return out


def _render_scene(config: DatasetConfig, index: int, object_set=None, progress: tqdm | None = None) -> int:
    """Sample scene ``index`` of the dataset, render it from every viewpoint, write its file; returns ``index``."""
    object_set = object_set if object_set is not None else object_set_from_config(config.objects)
    scene = scenes.sample_scene(object_set, config.scene, scene_seeds(config.seed, config.num_scenes)[index],
                                config.objects)
    views = render_scene_views(config, scene, scene_key(config.seed, index), object_set, progress)
    views.save(scene_file(config.out_dir, index))
    return index


def _finished(path: Path) -> bool:
    """A scene file that exists and reads back; a damaged one is rendered again."""
    if not path.exists():
        return False
    try:
        SceneViews.load(path)
    except ValueError as e:
        warnings.warn(f"{e}: rendering it again", stacklevel=3)
        return False
    return True


def export_recording(scene_views_file: str | Path, folder: str | Path, overwrite: bool = False) -> Path:
    """Write one rendered scene as a recorded sequence (``jaxcls.world.recording``'s folder format)."""
    views = SceneViews.load(scene_views_file)
    return recording.write_recording(folder, views.to_recording(), overwrite=overwrite)
