"""YAML configs loaded into typed, frozen dataclasses (OmegaConf structured configs).

Each concern owns one config block, a frozen dataclass defined beside the code it configures
(``world.objects.ObjectSetConfig``, ``perception.settings.VolumeConfig``, ...); a command's schema nests
the blocks it needs (``commands``). A YAML file fills it; unknown keys and wrong types are errors naming
the key and the file; dotted ``key.sub=value`` overrides from the command line apply last; every run saves
the resolved config beside its outputs.

Ranges are declared where a field is defined, with ``bounded(default, ge=..., lt=...)``; the block's
``__post_init__`` calls ``check_bounds(self)`` (Python callers), and ``load_config`` checks the whole tree
first so that the error names the dotted key (``sensor.random_dropout``) and the file it came from.

Choices are ``enum.StrEnum``s owned by the module that acts on them (``perception.settings.Segmenter``,
``planning.nbv.PolicyName``, ...), their members named as the YAML spells them: OmegaConf refuses any other
value naming the key and the choices; Python callers may pass the value (``segmenter="reference"``) and the
block's ``check_bounds`` turns it into the member. Code acts on a choice through its registry or the member
(``Segmenter.reference.on_host``), never by comparing strings (``tests/test_layout.py`` checks).
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

T = TypeVar("T")


class ConfigError(ValueError):
    """A config that does not fit its schema; the message names the file and the key."""


CONFIG_DIR = resources.files("jaxcls") / "configs"


def shipped_configs() -> list[str]:
    """Names of the configs shipped with the package (``jaxcls/configs/<name>.yaml``)."""
    return sorted(p.name.removesuffix(".yaml") for p in CONFIG_DIR.iterdir() if p.name.endswith(".yaml"))


def resolve_config(name: str | Path) -> Path:
    """A config file: ``name`` as a path if it exists, else the shipped config named ``name``, ``name.yaml``
    or ``configs/<name>.yaml`` (so ``synthetic`` and ``configs/synthetic.yaml`` work from any folder).
    Raises ConfigError listing the shipped configs."""
    path = Path(name)
    if path.is_file():
        return path
    shipped = Path(str(CONFIG_DIR / f"{path.name.removesuffix('.yaml')}.yaml"))
    if path.parent in (Path("."), Path("configs")) and shipped.is_file():
        return shipped
    raise ConfigError(f"{name}: config file not found (shipped configs: {', '.join(shipped_configs())})")


@dataclasses.dataclass(frozen=True)
class Bounds:
    """Allowed range of a number (or of each element of a tuple of numbers); None = unbounded."""

    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None

    def violation(self, value: Any) -> str | None:
        """Why ``value`` is out of range, or None."""
        if isinstance(value, list | tuple | ListConfig):
            for v in value:
                if (why := self.violation(v)) is not None:
                    return f"{why.split(', got')[0]} for each element, got {list(value)}"
            return None
        if isinstance(value, bool) or not isinstance(value, int | float):
            return None  # wrong types are the schema's business
        if not math.isfinite(value):
            return f"must be finite, got {value}"
        for bound, ok, word in ((self.ge, value >= (self.ge or 0), ">="), (self.gt, value > (self.gt or 0), ">"),
                                (self.le, value <= (self.le or 0), "<="), (self.lt, value < (self.lt or 0), "<")):
            if bound is not None and not ok:
                return f"must be {word} {bound}, got {value}"
        return None


def bounded(default: Any, *, ge: float | None = None, gt: float | None = None, le: float | None = None,
            lt: float | None = None) -> Any:
    """A dataclass field with a range, checked by ``check_bounds`` and ``load_config``."""
    return dataclasses.field(default=default, metadata={"bounds": Bounds(ge, gt, le, lt)})


def check_bounds(config: Any, prefix: str = "") -> None:
    """Raise ValueError naming ``prefix + field`` for the first field of ``config`` outside its bounds, or
    for a choice (a field whose default is an ``enum.Enum`` member) that is not one of its enum's values; a
    choice given as its value (``"reference"`` from Python code) becomes the member.

    Call it from a config block's ``__post_init__``; nested blocks check themselves when built.
    """
    for f in dataclasses.fields(config):
        kind, value = type(f.default), getattr(config, f.name)
        if isinstance(f.default, enum.Enum) and not isinstance(value, kind):
            try:
                object.__setattr__(config, f.name, kind(value))
            except ValueError:
                raise ValueError(f"{prefix}{f.name} must be one of {[str(m.value) for m in kind]}, got {value!r}"
                                 ) from None
        bounds = f.metadata.get("bounds")
        if bounds is not None and (why := bounds.violation(getattr(config, f.name))) is not None:
            raise ValueError(f"{prefix}{f.name} {why}")


def _check_tree(node: DictConfig, source: str, prefix: str = "") -> None:
    """``check_bounds`` over a merged, not yet built config tree, naming dotted keys and the source."""
    schema = OmegaConf.get_type(node)
    if not dataclasses.is_dataclass(schema):
        return
    for f in dataclasses.fields(schema):
        if f.name not in node:
            continue
        child = node[f.name] if isinstance(node._get_node(f.name), DictConfig) else None
        if child is not None:
            _check_tree(child, source, f"{prefix}{f.name}.")
            continue
        raw = node._get_node(f.name)
        value = OmegaConf.to_container(raw) if OmegaConf.is_config(raw) else raw._value()
        bounds = f.metadata.get("bounds")
        if bounds is not None and (why := bounds.violation(value)) is not None:
            raise ConfigError(f"{source}: key '{prefix}{f.name}' {why}")


# Keys of earlier versions that every saved config still holds, and what took their place: dropped from a file
# (its value is the one the run had: the same default), refused from the command line naming the new key.
RETIRED = {"viewpoints.candidate_radius": "nbv.radius (the planner owns the candidate radius)"}


def _drop_retired(layer: DictConfig, source: str, from_file: bool) -> None:
    for key, instead in RETIRED.items():
        parent, _, leaf = key.rpartition(".")
        node = OmegaConf.select(layer, parent) if parent else layer
        if isinstance(node, DictConfig) and leaf in node:
            if not from_file:
                raise ConfigError(f"{source}: key '{key}' is retired; use {instead}")
            del node[leaf]


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


def load_config(schema: type[T], path: str | Path | None = None, overrides: Sequence[str] = (),
                keep_only: type | None = None) -> T:
    """The schema's defaults, then the YAML file at ``path`` (if any), then dotted ``overrides``.

    keep_only: read only the file's top-level keys that are fields of this schema (``jaxcls show`` reads
    the world of a dataset config: ``WorldConfig``'s keys, not where the dataset goes or its seed).
    """
    cfg = _schema(schema)
    if path is not None:
        path = resolve_config(path)
        try:
            layer = OmegaConf.load(path)
        except Exception as e:  # the YAML parser's own errors carry the line
            raise ConfigError(f"{path}: not valid YAML: {e}") from None
        if layer is None or (isinstance(layer, DictConfig) and not layer and not path.read_text().strip()):
            raise ConfigError(f"{path}: the config file is empty (write at least one key, or leave out --config)")
        if not isinstance(layer, DictConfig):
            raise ConfigError(f"{path}: expected a mapping at the top level")
        _drop_retired(layer, str(path), from_file=True)
        if keep_only is not None:
            keep = {f.name for f in dataclasses.fields(keep_only)}
            for key in [k for k in layer if k not in keep]:
                del layer[key]
        cfg = _merge(cfg, layer, str(path))
        _check_tree(cfg, str(path))
    if overrides:
        bad = [o for o in overrides if "=" not in o]
        if bad:
            raise ConfigError(f"command line: overrides must look like key.sub=value, got {bad}")
        layer = OmegaConf.from_dotlist(list(overrides))
        _drop_retired(layer, "command line", from_file=False)
        cfg = _merge(cfg, layer, "command line")
        # ``key={...}`` on a plain mapping replaces it (``classifiers={paper: builtin_paper}``: that one
        # classifier, not the file's plus it); ``key.sub=value`` changes one entry; a block (a dataclass) merges.
        for key in (o.split("=", 1)[0].strip() for o in overrides if o.split("=", 1)[1].lstrip().startswith("{")):
            value = OmegaConf.select(layer, key)
            if isinstance(value, DictConfig) and OmegaConf.get_type(cfg, key) is dict:
                try:
                    OmegaConf.update(cfg, key, value, merge=False)
                except OmegaConfBaseException as e:
                    raise ConfigError(f"command line: key '{key}': {str(e).splitlines()[0]}") from None
        _check_tree(cfg, "command line")
    try:
        return OmegaConf.to_object(cfg)
    except OmegaConfBaseException as e:
        raise ConfigError(f"{path or 'defaults'}: {str(e).splitlines()[0]}") from None
    except ValueError as e:  # a block's own cross-field rule (__post_init__)
        where = f"{path} and the command line" if path and overrides else (path or "command line")
        raise ConfigError(f"{where}: {e}") from None


def to_yaml(config: Any) -> str:
    """The resolved config as YAML, readable back by ``load_config``."""
    if not dataclasses.is_dataclass(config):
        raise TypeError(f"to_yaml expects a config dataclass, got {type(config).__name__}")
    return OmegaConf.to_yaml(OmegaConf.structured(config))


def save_config(config: Any, path: str | Path) -> Path:
    """Write the resolved config beside a run's outputs."""
    from jaxcls import io

    return io.write_text(path, to_yaml(config))
