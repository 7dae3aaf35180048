"""YAML configs loaded into typed, frozen dataclasses (OmegaConf structured configs).

Each run's schema is a frozen dataclass owned by the module that runs it (``dataset.DatasetConfig``, ...).
A YAML file fills it; unknown keys and wrong types are errors naming the key and the file; dotted
``key.sub=value`` overrides from the command line apply last; every run saves the resolved config beside
its outputs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeVar

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

T = TypeVar("T")


class ConfigError(ValueError):
    """A config that does not fit its schema; the message names the file and the key."""


def _schema(schema: type[T]) -> DictConfig:
    base = OmegaConf.structured(schema)
    OmegaConf.set_readonly(base, False)
    return base


def _merge(base: DictConfig, layer: DictConfig, source: str) -> DictConfig:
    try:
        return OmegaConf.merge(base, layer)
    except OmegaConfBaseException as e:
        key = getattr(e, "full_key", None) or "?"
        msg = str(e).splitlines()[0]
        raise ConfigError(f"{source}: key '{key}': {msg}") from None


def load_config(schema: type[T], path: str | Path | None = None, overrides: Sequence[str] = ()) -> T:
    """The schema's defaults, then the YAML file at ``path`` (if any), then dotted ``overrides``."""
    cfg = _schema(schema)
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"{path}: config file not found")
        try:
            layer = OmegaConf.load(path)
        except Exception as e:  # the YAML parser's own errors carry the line
            raise ConfigError(f"{path}: not valid YAML: {e}") from None
        if not isinstance(layer, DictConfig):
            raise ConfigError(f"{path}: expected a mapping at the top level")
        cfg = _merge(cfg, layer, str(path))
    if overrides:
        bad = [o for o in overrides if "=" not in o]
        if bad:
            raise ConfigError(f"command line: overrides must look like key.sub=value, got {bad}")
        cfg = _merge(cfg, OmegaConf.from_dotlist(list(overrides)), "command line")
    try:
        return OmegaConf.to_object(cfg)
    except OmegaConfBaseException as e:
        raise ConfigError(f"{path or 'defaults'}: {str(e).splitlines()[0]}") from None


def to_yaml(config: Any) -> str:
    """The resolved config as YAML, readable back by ``load_config``."""
    if not dataclasses.is_dataclass(config):
        raise TypeError(f"to_yaml expects a config dataclass, got {type(config).__name__}")
    return OmegaConf.to_yaml(OmegaConf.structured(config))


def save_config(config: Any, path: str | Path) -> Path:
    """Write the resolved config beside a run's outputs."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(to_yaml(config))
    return path
