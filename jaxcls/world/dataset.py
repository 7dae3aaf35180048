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
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import warnings
import zipfile
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxcls import geometry, io
from jaxcls.config import bounded, check_bounds, load_config, save_config
from jaxcls.world import recording, scenes
from jaxcls.world.objects import object_set_from_config
from jaxcls.world.render import resolve_backend
from jaxcls.world.setup import WorldConfig, make_world


@dataclasses.dataclass(frozen=True)
class DatasetConfig(WorldConfig):
    """``jaxcls dataset``: the world (``WorldConfig``: objects, scene, camera, viewpoints, sensor, backend),
    how many scenes, where to."""

    name: str = "synthetic"
    out_dir: str = "data/synthetic"
    num_scenes: int = bounded(7, ge=1)
    seed: int = 0
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
        w, h, fx, fy, cx, cy = arrays["intrinsics"].tolist()
        return cls(scene=scenes.Scene.from_dict(json.loads(str(arrays["scene_json"])), source=str(path)),
                   intrinsics=geometry.Intrinsics(width=int(w), height=int(h), fx=fx, fy=fy, cx=cx, cy=cy),
                   depth=arrays["depth"], object_id=arrays["object_id"].astype(np.int32),
                   T_wc=arrays["T_wc"], T_wc_true=arrays["T_wc_true"],
                   backend=str(arrays.get("backend", "unknown")))

    def to_recording(self) -> recording.Recording:
        """The recorded-sequence form a real sensor would produce (depth rounded to millimetres)."""
        return recording.Recording(depth=self.depth, T_wc=self.T_wc, intrinsics=self.intrinsics,
                                   table_height=self.scene.table_height, scene=self.scene.to_dict())


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
        if config.workers == 1 or len(todo) <= 1:
            for i in todo:
                bar.set_postfix(scene=i)
                _render_scene(config, i, object_set, bar)
            return out
        if resolve_backend(config.backend) != "mujoco":
            raise ValueError(f"workers={config.workers}: scenes render in parallel with the CPU renderer only; "
                             f"set backend=mujoco (backend={config.backend!r} resolves to "
                             f"{resolve_backend(config.backend)!r}) or workers=1")
        config = dataclasses.replace(config, backend="mujoco")
        # Spawned, not forked (JAX is threaded); each worker renders and writes whole scenes.
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(min(config.workers, len(todo)), mp_context=context,
                                 initializer=_cpu_worker) as pool:
            for done in as_completed([pool.submit(_render_scene, config, i) for i in todo]):
                bar.set_postfix(scene=done.result())
                bar.update(config.viewpoints.count)
    return out


def _cpu_worker() -> None:
    """A rendering worker keeps JAX (the sensor model's noise) on the CPU: a GPU host's workers would each
    claim most of the GPU's memory."""
    jax.config.update("jax_platforms", "cpu")


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
