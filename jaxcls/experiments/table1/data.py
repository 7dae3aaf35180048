"""Table 1's scenes (a ``jaxcls dataset`` folder or config, rendered first where missing) and its stored
episodes."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from jaxcls import io
from jaxcls.config import ConfigError, load_config, resolve_config
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.world.dataset import DatasetConfig, build_dataset, scene_file


def dataset_config(config: Table1Config) -> DatasetConfig:
    """The dataset's config, from its folder or its name, without reading or rendering a scene."""
    folder = Path(config.dataset)
    if folder.is_dir() and (folder / "config.yaml").is_file():
        return load_config(DatasetConfig, folder / "config.yaml", config.dataset_overrides)
    return load_config(DatasetConfig, config.dataset, config.dataset_overrides)


def stored_records(config: Table1Config, store: Path) -> list[dict[str, Any]]:
    """The stored episodes of this config's classifiers, rows and first ``scenes`` scenes (all if 0)."""
    return [r for r in io.read_jsonl(store) if r["classifier"] in config.classifiers and r["row"] in config.rows
            and (not config.scenes or int(r["scene"]) < config.scenes)]


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
