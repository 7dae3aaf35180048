"""Table 1's scenes (a ``jaxcls dataset`` folder or config, rendered first where missing; or drawn from the
dataset config and rendered where the episodes run, ``SceneSource.device``) and its stored episodes."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from jaxcls import devices, io
from jaxcls.config import ConfigError, load_config, resolve_config
from jaxcls.episode import protocol, sources
from jaxcls.experiments.table1.config import SceneSource, Table1Config
from jaxcls.world.dataset import DatasetConfig, build_dataset, scene_file, scene_key, scene_seeds
from jaxcls.world.render.types import Backend


def dataset_config(config: Table1Config) -> DatasetConfig:
    """The dataset's config, from its folder or its name, without reading or rendering a scene."""
    folder = Path(config.dataset)
    if folder.is_dir() and (folder / "config.yaml").is_file():
        return load_config(DatasetConfig, folder / "config.yaml", config.dataset_overrides)
    return load_config(DatasetConfig, config.dataset, config.dataset_overrides)


def process_store(store: Path, process: tuple[int, int] = (0, 1)) -> Path:
    """Where process ``index`` of ``count`` (``process``) appends its episodes: ``store`` itself for one process,
    else ``<stem>.<index>.jsonl`` beside it (no two processes append to one file)."""
    index, count = process
    return store if count == 1 else store.with_name(f"{store.stem}.{index}{store.suffix}")


def read_stores(store: Path) -> list[dict[str, Any]]:
    """The records of ``store`` and of every process's store beside it (``process_store``), and of their ``.xz``
    archives (``results/`` keeps a run's episodes so): a run's episodes whichever processes (and however many)
    stored them. (An episode in both a store and its archive is there twice: ``of_config`` keeps the first.)"""
    archives = [store.with_name(store.name + ".xz"),
                *sorted(store.parent.glob(f"{store.stem}.*{store.suffix}.xz"))]
    return [r for path in [*store_paths(store), *archives] for r in io.read_jsonl(path)]


def store_paths(store: Path) -> list[Path]:
    """``store`` and every process's store beside it (``process_store``), whether they exist or not yet."""
    return [store, *sorted(store.parent.glob(f"{store.stem}.*{store.suffix}"))]


def stored_records(config: Table1Config, store: Path) -> list[dict[str, Any]]:
    """The stored episodes (every process's, ``read_stores``) of this config (``of_config``)."""
    return of_config(config, read_stores(store))


def record_key(r: dict[str, Any]) -> tuple[str, str, int, int]:
    """An episode's identity in the store: (classifier, row, scene, run)."""
    return r["classifier"], r["row"], int(r["scene"]), int(r["run"])


def paired_runs(first: Sequence[dict[str, Any]], second: Sequence[dict[str, Any]]
                ) -> dict[tuple[str, str], tuple[list[dict[str, Any]], list[dict[str, Any]]]]:
    """(classifier, row) -> (the first run's episodes, the second's): the (scene, run) episodes both runs stored
    (``record_key``), in the same order (scene, then run), each once; rows either run lacks are left out."""
    def index(records):
        out: dict[tuple[str, str, int, int], dict[str, Any]] = {}
        for r in records:
            out.setdefault(record_key(r), r)
        return out

    a, b = index(first), index(second)
    pairs: dict[tuple[str, str], tuple[list, list]] = {}
    for key in sorted(a.keys() & b.keys()):
        x, y = pairs.setdefault(key[:2], ([], []))
        x.append(a[key])
        y.append(b[key])
    return pairs


def settings_differ(a: Table1Config, b: Table1Config) -> list[str]:
    """The keys (dotted, sorted) in which two Table 1 configs' results-defining settings differ: [] for the same."""
    def flat(tree, prefix=""):
        out = {}
        for k, v in tree.items():
            if isinstance(v, dict):
                out.update(flat(v, f"{prefix}{k}."))
            else:
                out[f"{prefix}{k}"] = v
        return out

    x, y = flat(a.results_defining()), flat(b.results_defining())
    return sorted(k for k in x.keys() | y.keys() if x.get(k) != y.get(k))


def of_config(config: Table1Config, records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The episodes of ``records`` of this config's classifiers, rows and first ``scenes`` scenes (all if 0),
    the oracle's on its first ``oracle_scenes`` (``runner.run_episodes``' rule), each (classifier, row, scene,
    run) once (its first)."""
    kept: dict[tuple, dict[str, Any]] = {}
    for r in records:
        if (r["classifier"] in config.classifiers and r["row"] in config.rows
                and (not config.scenes or int(r["scene"]) < config.scenes)
                and (protocol.ROWS[r["row"]].kind is not protocol.Kind.ORACLE
                     or int(r["scene"]) < config.oracle_scenes)):
            kept.setdefault(record_key(r), r)
    return list(kept.values())


def follow_other_stores(store: Path, process: tuple[int, int]) -> io.JsonlFollower:
    """The records the other processes of a run append to their stores (and the one-process store), read while
    they run (``io.JsonlFollower``): process 0 has them for the tables when the last process ends."""
    mine = process_store(store, process)
    return io.JsonlFollower(lambda: [path for path in store_paths(store) if path != mine])


def open_dataset(config: Table1Config) -> tuple[DatasetConfig, list[Path]]:
    """The dataset's config and its scene files (``config.scenes`` of them), rendering a config's missing
    scenes first (``build_dataset`` resumes)."""
    folder = Path(config.dataset)
    if folder.is_dir():
        if not (folder / "config.yaml").is_file():
            raise ValueError(f"dataset: {folder} has no config.yaml; pass a folder written by `jaxcls dataset`")
        dataset = load_config(DatasetConfig, folder / "config.yaml", config.dataset_overrides)
        dataset = dataclasses.replace(dataset, out_dir=str(folder))
        files = sorted(folder.glob("scene_*.npz"))
        if not files:
            raise ValueError(f"dataset: {folder} holds no scene files (scene_NNN.npz)")
    else:
        try:
            resolve_config(config.dataset)
        except ConfigError as e:
            raise ValueError(f"dataset: {config.dataset!r} is neither a dataset folder nor a dataset config "
                             f"({e})") from None
        dataset = load_config(DatasetConfig, config.dataset, config.dataset_overrides)
        if config.scenes > dataset.num_scenes:
            raise ValueError(f"scenes: {config.scenes} scenes asked, the dataset {config.dataset!r} has "
                             f"{dataset.num_scenes} (dataset_overrides=[num_scenes={config.scenes},out_dir=...])")
        build_dataset(dataset)
        files = [scene_file(dataset.out_dir, i) for i in range(dataset.num_scenes)]
    if config.scenes > len(files):
        raise ValueError(f"scenes: {config.scenes} scenes asked, {folder} has {len(files)}")
    return dataset, files[:config.scenes or len(files)]


@dataclasses.dataclass(frozen=True, eq=False)
class Scenes:
    """Table 1's ``count`` scenes by index: read from a dataset's ``files``, or (``files`` empty) drawn from
    the dataset config with its seeds and rendered on demand from one ``SceneBank`` by ``backend`` (``warp`` on
    a GPU, MuJoCo's C caster on a CPU), through the config's sensor with each scene's key: the frames
    ``jaxcls dataset`` writes, within the renderers' agreement."""

    dataset: DatasetConfig
    count: int
    files: tuple[Path, ...] = ()
    backend: Backend = Backend.mujoco

    @classmethod
    def from_files(cls, dataset: DatasetConfig, files: Sequence[Path]) -> Scenes:
        return cls(dataset=dataset, count=len(files), files=tuple(files))

    @property
    def on_device(self) -> bool:
        """Whether the frames are rendered on a device (``warp``), not read from files or cast on the CPU."""
        return not self.files and self.backend is Backend.warp

    def load(self, indices: Sequence[int]) -> list[sources.Preloaded]:
        """The frames of scenes ``indices`` (every viewpoint) on the host, one ``Preloaded`` each (checked)."""
        if self.files:
            return [sources.dataset_source(self.files[i], self.dataset.objects) for i in indices]
        chunk = self.chunk(indices)
        return [sources.Preloaded(depth=np.asarray(chunk.depth[n]), T_wc=chunk.T_wc[n], intrinsics=chunk.intrinsics,
                                  table_height=scene.table_height, scene=scene, name=f"scene {i} (rendered)")
                for n, (i, scene) in enumerate(zip(indices, chunk.scenes, strict=True))]

    def frame_layout(self) -> tuple[Any, float, int]:
        """(camera intrinsics, table height m, viewpoints V) of every scene's frames, from the dataset's config:
        known before a frame is rendered or read (a program for the frames' shapes can be loaded meanwhile)."""
        return self.dataset.camera.intrinsics(), self.dataset.scene.table_height, self.dataset.viewpoints.count

    def prepare_renderer(self) -> None:
        """Build what rendering needs (the scene bank and its renderer, drawn scenes aside), rendering nothing:
        host work that a program loaded on another thread meanwhile may overlap, whatever the renderer
        (``loads_beside_renders``). Nothing to do for a dataset's files."""
        if self.on_device:
            bank = _bank(self.dataset.objects, self.dataset.scene, self.dataset.camera)[1]
            bank.warp_renderer()  # (built once and kept by the bank)

    def loads_beside_renders(self) -> bool:
        """Whether a program may be loaded on another thread (``compile_cache.ahead``) while ``chunk`` renders:
        the renderer's word (``WarpRenderer.loads_beside_renders``: not under MuJoCo Warp's own CUDA graph
        capture); always for a dataset's files and MuJoCo's C caster. Known before the renderer is built."""
        if not self.on_device:
            return True
        from jaxcls.world.bank import KINEMATICS
        from jaxcls.world.render.factory import loads_beside_renders

        return loads_beside_renders(KINEMATICS)

    def chunk_ahead(self, indices: Sequence[int]) -> Future[Chunk]:
        """``chunk(indices)`` on a thread of its own, the renderer built there first (``prepare_renderer``); the
        Future is done once the frames are (on the device too): e.g. a process's first frames made while it
        loads its classifiers. Only where ``loads_beside_renders`` (ValueError otherwise); nothing else may
        build the renderer or render until it is done."""
        if not self.loads_beside_renders():
            raise ValueError("Scenes.chunk_ahead: this renderer forbids work beside its renders (loads_beside_renders)")
        import jax

        def make() -> Chunk:
            self.prepare_renderer()
            chunk = self.chunk(indices)
            jax.block_until_ready(chunk.depth)
            return chunk

        pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxcls-frames")
        try:
            return pool.submit(make)
        finally:
            pool.shutdown(wait=False)

    def chunk(self, indices: Sequence[int]) -> Chunk:
        """The frames of scenes ``indices`` stacked for a batched call, on the device when rendered there."""
        if self.files:
            views = self.load(indices)
            return Chunk(scenes=[v.scene for v in views], depth=np.stack([v.depth for v in views]),
                         T_wc=np.stack([v.T_wc for v in views]), intrinsics=views[0].intrinsics)
        beyond = [i for i in indices if not 0 <= i < self.dataset.num_scenes]
        if beyond:
            raise ValueError(f"Scenes.chunk: scenes {beyond} asked of a draw of {self.dataset.num_scenes} "
                             f"(dataset num_scenes)")
        return _render(self.dataset, tuple(indices), self.backend)


@dataclasses.dataclass(frozen=True, eq=False)
class Chunk:
    """S scenes' frames from every viewpoint: depth [S, V, H, W] m (NumPy, or a JAX array where they were
    rendered), T_wc [S, V, 4, 4] f64 the poses the pipeline is told; the scenes; the camera."""

    scenes: list
    depth: Any
    T_wc: np.ndarray
    intrinsics: Any


def _render(dataset: DatasetConfig, indices: tuple[int, ...], backend: Backend) -> Chunk:
    """Scenes ``indices`` of ``dataset`` drawn with its seeds, rendered from the bank, through its sensor with
    each scene's key (``jaxcls dataset``'s draw); the frames stay where they were rendered."""
    import jax

    from jaxcls.world import scenes
    from jaxcls.world.bank import KINEMATICS
    from jaxcls.world.render.sensor import measure_scenes
    from jaxcls.world.setup import make_world

    object_set, bank = _bank(dataset.objects, dataset.scene, dataset.camera)
    seeds = scene_seeds(dataset.seed, max(indices, default=-1) + 1)  # (the draw's first: the same whatever its count)
    drawn = [scenes.sample_scene(object_set, dataset.scene, seeds[i], dataset.objects) for i in indices]
    T_true = np.stack([make_world(dataset.world_config(), scene=s, object_set=object_set).viewpoints for s in drawn])
    frames = bank.render(drawn, T_true, backend, batch=1024, kinematics=KINEMATICS)  # (loads_beside_renders')
    with jax.default_device(devices.host_cpu()):  # keys on the host: nothing waits for a GPU
        keys = [scene_key(dataset.seed, i) for i in indices]
    depth, T_wc = measure_scenes(keys, frames.depth, T_true, bank.intrinsics, dataset.sensor)  # (one program)
    return Chunk(scenes=drawn, depth=depth, T_wc=T_wc, intrinsics=bank.intrinsics)


@functools.lru_cache(maxsize=4)
def _bank(objects, scene, camera):
    """(object set, scene bank) of a dataset's objects, scene and camera blocks, built once in a process."""
    from jaxcls.world.bank import SceneBank
    from jaxcls.world.objects import object_set_from_config

    object_set = object_set_from_config(objects)
    return object_set, SceneBank.build(object_set, scene, camera.intrinsics())


def open_scenes(config: Table1Config) -> tuple[DatasetConfig, Scenes]:
    """Table 1's scenes by ``config.scene_source``: a dataset's files (``open_dataset``), or its config's
    scenes rendered where the episodes run (warp where a CUDA GPU and MuJoCo Warp are present, else MuJoCo's
    C caster), none written to disk."""
    if config.scene_source is SceneSource.dataset:
        dataset, files = open_dataset(config)
        return dataset, Scenes.from_files(dataset, files)
    from jaxcls.world.render import resolve_backend

    dataset = dataset_config(config)
    if config.scenes > dataset.num_scenes:
        raise ValueError(f"scenes: {config.scenes} scenes asked, the dataset config has {dataset.num_scenes} "
                         f"(dataset_overrides=[num_scenes={config.scenes}])")
    # The bank renders with warp on a GPU, else with MuJoCo's C caster (for ``mjx`` too).
    backend = Backend.warp if resolve_backend(dataset.backend) is Backend.warp else Backend.mujoco
    return dataset, Scenes(dataset=dataset, count=config.scenes or dataset.num_scenes, backend=backend)
