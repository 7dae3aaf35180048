"""Object sets from files: class folders (``load_folder``), BOP datasets (``load_bop``), and the ``objects:``
config section (``ObjectSetConfig``) that picks one of them or a procedural set (``ProceduralSet``: builtin,
lookalike) (``load_object_set``)."""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.distance import pdist

from jaxcls.world.objects.builtin import builtin_object_set
from jaxcls.world.objects.lookalike import lookalike_object_set
from jaxcls.world.objects.mesh import (
    MESH_SUFFIXES,
    UP_AXES,
    _read_mesh,
    _sample_rng,
    _surface_samples,
    _up_rotation,
    normalise_mesh,
)
from jaxcls.world.objects.model import ObjectModel, ObjectSet

# Largest extent (metres, after ``scale``) a loaded model may have: tabletop objects are far inside these
# bounds, and a model outside them almost surely has the wrong units (millimetres without scale=0.001, ...).
MAX_MODEL_EXTENT = 5.0
MIN_MODEL_EXTENT = 0.001

_BOP_FIELDS = ("min_x", "min_y", "min_z", "size_x", "size_y", "size_z")


# ----------------------------------------------------------------------------------------------------------
# Class folders


def _check_extent(mesh: trimesh.Trimesh, path: Path, scale: float) -> None:
    """Catch models in the wrong units at load time, naming the file and the fix."""
    extent = float(np.ptp(np.asarray(mesh.vertices), axis=0).max())
    if extent > MAX_MODEL_EXTENT:
        if scale == 1.0:
            hint = ("the model looks like millimetres: set objects.scale=0.001 (from Python, pass scale=0.001 "
                    "to load_folder / load_object_set)")
        else:
            hint = ("check the file's units: objects.scale (the scale argument from Python) multiplies its "
                    "coordinates to give metres, 0.001 for millimetres")
        raise ValueError(f"{path}: largest extent {extent:.4g} m with objects.scale={scale:g} is over "
                         f"{MAX_MODEL_EXTENT:g} m; {hint}")
    if extent < MIN_MODEL_EXTENT:
        if scale < 1.0:
            hint = (f"the file may already be in metres with a wrong scale: leave objects.scale at 1 (from "
                    f"Python, the scale argument of load_folder / load_object_set), not {scale:g}")
        else:
            hint = ("check the file's units: objects.scale (the scale argument from Python) multiplies its "
                    "coordinates to give metres")
        raise ValueError(f"{path}: largest extent {extent:.4g} m with objects.scale={scale:g} is under "
                         f"{MIN_MODEL_EXTENT * 1000:g} mm; {hint}")


def _model_from_file(path: Path, name: str, class_name: str, scale: float, up_axis: str,
                     surface_samples: int) -> ObjectModel:
    raw = _read_mesh(path)
    try:
        mesh = normalise_mesh(raw, scale=scale, up_axis=up_axis)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from error
    _check_extent(mesh, path, scale)
    points, normals = _surface_samples(mesh, surface_samples, _sample_rng(name))
    return ObjectModel(name, class_name, mesh, points, normals)


def _split_by_class(name: str, models: Sequence[ObjectModel], test_fraction: float) -> ObjectSet:
    """Hold out the last ``round(n * test_fraction)`` instances of each class (at least one stays train)."""
    if not 0.0 <= test_fraction < 1.0:
        raise ValueError(f"test_fraction must be in [0, 1), got {test_fraction}")
    classes = tuple(sorted({m.class_name for m in models}))
    train: list[ObjectModel] = []
    test: list[ObjectModel] = []
    for class_name in classes:
        members = [m for m in models if m.class_name == class_name]
        n_test = min(len(members) - 1, math.floor(len(members) * test_fraction + 0.5))
        train += members[:len(members) - n_test]
        test += members[len(members) - n_test:]
    return ObjectSet(name, classes, tuple(train), tuple(test))


def load_folder(path: str | os.PathLike, test_fraction: float = 0.0, surface_samples: int = 2048,
                scale: float = 1.0, up_axis: str = "z") -> ObjectSet:
    """Models laid out as ``path/<class>/<instance>.{obj,ply,stl}``.

    scale: multiplies the file's coordinates to give metres (0.001 for mm); up_axis: the files' up
    direction. Instances are sorted by file name; the last ``test_fraction`` of each class is held out.
    Instance names are ``<class>_<stem>``. A model whose largest extent (after ``scale``) is over
    ``MAX_MODEL_EXTENT`` or under ``MIN_MODEL_EXTENT`` is an error naming the file: its units are wrong.
    """
    root = Path(path)
    if not root.is_dir():
        raise FileNotFoundError(f"object folder not found: {root}")
    _up_rotation(up_axis)
    models: list[ObjectModel] = []
    for entry in sorted(root.iterdir()):
        if entry.name.startswith("."):
            continue
        if entry.is_file():
            if entry.suffix.lower() in MESH_SUFFIXES:
                raise ValueError(f"{entry}: meshes must be in one subfolder per class, not in {root}")
            continue
        files = sorted(f for f in entry.iterdir() if f.is_file() and f.suffix.lower() in MESH_SUFFIXES)
        if not files:
            raise ValueError(f"{entry}: class folder has no {'/'.join(MESH_SUFFIXES)} meshes")
        seen: dict[str, Path] = {}
        for file in files:
            name = f"{entry.name}_{file.stem}"
            if name in seen:
                raise ValueError(f"{file}: instance name {name!r} is also used by {seen[name]}")
            seen[name] = file
            models.append(_model_from_file(file, name, entry.name, scale, up_axis, surface_samples))
    if not models:
        raise ValueError(f"{root}: no class subfolders with meshes")
    return _split_by_class(root.name, models, test_fraction)


# ----------------------------------------------------------------------------------------------------------
# BOP


def _read_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: cannot read JSON ({error})") from error
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object keyed by object id")
    return data


def _parse_id(key: str, source: Path) -> int:
    try:
        return int(key)
    except ValueError:
        raise ValueError(f"{source}: key {key!r} is not an integer object id") from None


def _max_distance(vertices: np.ndarray) -> float:
    """Largest distance between two vertices (BOP's ``diameter``), via the convex hull (all vertices when
    Qhull cannot build one: fewer than 4 points, or all of them coplanar)."""
    try:
        points = vertices[ConvexHull(vertices).vertices]
    except (QhullError, ValueError):
        points = vertices
    return float(pdist(points).max()) if len(points) > 1 else 0.0


def models_info(vertices: np.ndarray) -> dict[str, float]:
    """BOP's ``models_info.json`` entry of a model with ``vertices`` [V, 3] (in the file's units, mm in BOP):
    ``min_x/y/z``, ``size_x/y/z`` and ``diameter`` (the largest distance between two vertices)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    lo, size = vertices.min(axis=0), np.ptp(vertices, axis=0)
    info = {f"{kind}_{a}": float(v[i]) for kind, v in (("min", lo), ("size", size)) for i, a in enumerate("xyz")}
    return {**info, "diameter": _max_distance(vertices)}


def _check_models_info(mesh: trimesh.Trimesh, info: Mapping, file: Path, info_path: Path, key: str) -> None:
    """Sizes, minima and diameter in mm must agree with the mesh within max(1 mm, 1 %)."""
    if not isinstance(info, Mapping):
        raise ValueError(f"{info_path}: key {key!r} must map to an object")
    values = {}
    for field in (*_BOP_FIELDS, "diameter"):
        if field not in info:
            if field == "diameter":
                continue
            raise ValueError(f"{info_path}: key {key!r} lacks {field!r}")
        try:
            values[field] = float(info[field])
        except (TypeError, ValueError):
            raise ValueError(f"{info_path}: key {key!r} field {field!r} is not a number") from None
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    if not np.isfinite(vertices).all():
        return
    measured = models_info(vertices)
    tolerance = {f"{kind}_{a}": max(1.0, 0.01 * abs(values[f"size_{a}"]))
                 for kind in ("min", "size") for a in "xyz"}
    if "diameter" in values:
        tolerance["diameter"] = max(1.0, 0.01 * abs(values["diameter"]))
    else:
        del measured["diameter"]
    for field, value in measured.items():
        if abs(value - values[field]) > tolerance[field]:
            raise ValueError(f"inconsistent models_info: {info_path} key {key!r} has {field} = "
                             f"{values[field]:g} mm but {file} measures {value:g} mm")


def _class_names(root: Path, class_names: Mapping[int, str] | None) -> dict[int, str]:
    if class_names is not None:
        return {int(k): str(v) for k, v in class_names.items()}
    for file_name in ("classes.json", "class_names.json"):
        file = root / file_name
        if file.is_file():
            names = {}
            for key, value in _read_json(file).items():
                if not isinstance(value, str) or not value:
                    raise ValueError(f"{file}: key {key!r} must map to a class name string")
                names[_parse_id(key, file)] = value
            return names
    return {}


def load_bop(path: str | os.PathLike, class_names: dict[int, str] | None = None, test_fraction: float = 0.0,
             surface_samples: int = 2048, up_axis: str = "z") -> ObjectSet:
    """A BOP dataset folder (as LINEMOD ships): ``path/models/obj_000001.ply`` in mm and
    ``path/models/models_info.json``; ``path`` may also be the ``models`` folder itself.

    class_names: object id -> class; else ``classes.json`` or ``class_names.json`` in ``path`` (keys are id
    strings); ids without a name get the class ``obj_000001``. Instance names are always ``obj_000001``.
    Each model is checked against models_info before it is converted to metres and ``up_axis`` turned to +z.
    """
    root = Path(path)
    if not root.is_dir():
        raise FileNotFoundError(f"BOP folder not found: {root}")
    models_dir = root / "models"
    if not models_dir.is_dir():
        if (root / "models_info.json").is_file():
            models_dir, root = root, root.parent
        else:
            raise FileNotFoundError(f"BOP folder has no models/ subfolder: {models_dir}")
    info_path = models_dir / "models_info.json"
    if not info_path.is_file():
        raise FileNotFoundError(f"BOP models_info not found: {info_path}")
    _up_rotation(up_axis)
    info = {_parse_id(key, info_path): (key, value) for key, value in _read_json(info_path).items()}
    if not info:
        raise ValueError(f"{info_path}: no objects")
    files: dict[int, Path] = {}
    for file in sorted(models_dir.glob("*.ply")):
        match = re.fullmatch(r"obj_(\d+)\.ply", file.name)
        if match is None:
            raise ValueError(f"{file}: not a BOP model name (expected obj_NNNNNN.ply)")
        obj_id = int(match.group(1))
        if obj_id not in info:
            raise ValueError(f"{file}: object id {obj_id} has no entry in {info_path}")
        files[obj_id] = file
    for obj_id, (key, _) in sorted(info.items()):
        if obj_id not in files:
            raise FileNotFoundError(f"{info_path}: key {key!r} has no model file "
                                    f"{models_dir / f'obj_{obj_id:06d}.ply'}")
    names = _class_names(root, class_names)
    unknown = sorted(set(names) - set(info))
    if unknown:
        raise ValueError(f"class names given for ids {unknown} that {info_path} does not list")
    models = []
    for obj_id in sorted(info):
        file, (key, entry) = files[obj_id], info[obj_id]
        name = f"obj_{obj_id:06d}"
        raw = _read_mesh(file)
        _check_models_info(raw, entry, file, info_path, key)
        try:
            mesh = normalise_mesh(raw, scale=0.001, up_axis=up_axis)
        except ValueError as error:
            raise ValueError(f"{file}: {error}") from error
        points, normals = _surface_samples(mesh, surface_samples, _sample_rng(name))
        models.append(ObjectModel(name, names.get(obj_id, name), mesh, points, normals))
    return _split_by_class(root.name, models, test_fraction)


def _is_bop(root: Path) -> bool:
    return (root / "models" / "models_info.json").is_file() or (root / "models_info.json").is_file()


def _missing_models_info(root: Path) -> Path | None:
    """The ``models_info.json`` that a BOP-looking folder lacks: ``root/models`` (or ``root``) holds
    ``obj_*.ply`` models but no models_info; None for anything else."""
    for models_dir in (root / "models", root):
        if (models_dir.is_dir() and any(models_dir.glob("obj_*.ply"))
                and not (models_dir / "models_info.json").is_file()):
            return models_dir / "models_info.json"
    return None


# ----------------------------------------------------------------------------------------------------------
# Dispatch and config


class ProceduralSet(enum.StrEnum):
    """The object sets made from seeds, without files: the names ``objects.source`` may take besides a folder
    (a folder of the same name is not read). Each builds with ``seed``, ``train_per_class``,
    ``test_per_class`` and ``surface_samples`` (``ProceduralSet.load``)."""

    builtin = "builtin"  # eight household classes (builtin.py)
    lookalike = "lookalike"  # nine classes in lookalike groups, the hard protocol's (lookalike.py)

    @classmethod
    def of(cls, source: str) -> ProceduralSet | None:
        """The procedural set ``source`` names, None for anything else (a folder)."""
        return cls(source) if source in cls._value2member_map_ else None

    def load(self, **kwargs) -> ObjectSet:
        """The set, cached by its builder (the same arguments return the same object)."""
        builder = {ProceduralSet.builtin: builtin_object_set, ProceduralSet.lookalike: lookalike_object_set}[self]
        return builder(**kwargs)


def load_object_set(source: str, **kwargs) -> ObjectSet:
    """A procedural set's name (``ProceduralSet``: ``"builtin"``, ``"lookalike"``) -> that set built with
    ``kwargs``; a folder with ``models/models_info.json`` (or a ``models`` folder holding it) -> ``load_bop``;
    any other folder -> ``load_folder``.

    A folder that holds BOP models (``obj_*.ply`` in ``models/`` or in itself) without their
    ``models_info.json`` is an error naming the missing file, rather than a class folder named ``models``.
    """
    procedural = ProceduralSet.of(source)
    if procedural is not None:
        return procedural.load(**kwargs)
    root = Path(source)
    if not root.is_dir():
        names = ", ".join(repr(str(p)) for p in ProceduralSet)
        raise FileNotFoundError(f"object set source is neither a procedural set ({names}) nor a folder: {source}")
    if _is_bop(root):
        return load_bop(root, **kwargs)
    missing = _missing_models_info(root)
    if missing is not None:
        raise FileNotFoundError(
            f"BOP models_info not found: {missing}; {missing.parent} holds BOP models (obj_*.ply) and a BOP "
            f"dataset needs their models_info.json (sizes and diameters in mm, as BOP ships it). For your own "
            f"meshes, use one subfolder per class instead")
    return load_folder(root, **kwargs)


@dataclasses.dataclass(frozen=True)
class ObjectSetConfig:
    """Which object set a run uses: the ``objects:`` section of a YAML config, recorded in scene JSON.

    source: a procedural set (``"builtin"``, ``"lookalike"``: ``ProceduralSet``), a BOP folder or a
    class-folder layout (``load_object_set``). Fields that the chosen source does not use must keep their
    defaults, so that a setting is never silently ignored.
    Out-of-range values are a ValueError naming the key (``objects.<field>``) when the config is built.

    clutter_source: where a scene's clutter objects (``scene.num_clutter``, never scored) come from. ``""``
    (the default): other instances of the scene's split of this set, as the paper's real scenes did with
    their own objects; else another object set (a procedural set, a BOP folder or class folders, metres, z up,
    its default settings and ``surface_samples``), every instance of which may stand on the table as
    clutter: generic shapes that the classifier never learnt (``ObjectSet.clutter``).
    """

    source: str = "builtin"
    seed: int = 0
    train_per_class: int = 8
    test_per_class: int = 4
    surface_samples: int = 2048
    test_fraction: float = 0.0
    scale: float = 1.0
    up_axis: str = "z"
    clutter_source: str = ""

    def __post_init__(self) -> None:
        def check(ok: bool, field: str, rule: str) -> None:
            if not ok:
                raise ValueError(f"objects.{field} must be {rule}, got {getattr(self, field)!r}")

        check(self.surface_samples >= 1, "surface_samples", ">= 1")
        for field in ("seed", "train_per_class", "test_per_class"):
            check(getattr(self, field) >= 0, field, ">= 0")
        check(0.0 <= self.test_fraction < 1.0, "test_fraction", "in [0, 1)")
        check(math.isfinite(self.scale) and self.scale > 0, "scale", "positive and finite (0.001 for mm)")
        check(self.up_axis in UP_AXES, "up_axis", f"one of {', '.join(UP_AXES)}")

    def loader_kwargs(self) -> dict:
        """Keyword arguments of the loader that ``load_object_set(self.source, ...)`` dispatches to."""
        if ProceduralSet.of(self.source) is not None:
            used = ("seed", "train_per_class", "test_per_class", "surface_samples")
        elif _is_bop(Path(self.source)):
            used = ("test_fraction", "surface_samples", "up_axis")
        else:
            used = ("test_fraction", "surface_samples", "scale", "up_axis")
        default = ObjectSetConfig()
        unused = [f.name for f in dataclasses.fields(self)
                  if f.name not in (*used, "source", "clutter_source")
                  and getattr(self, f.name) != getattr(default, f.name)]
        if unused:
            raise ValueError(f"objects: {unused} do not apply to source {self.source!r}")
        return {name: getattr(self, name) for name in used}


def object_set_from_config(config: ObjectSetConfig) -> ObjectSet:
    """The object set a config names (a procedural one comes from the cache), with the clutter instances of
    ``clutter_source`` where one is given (named ``clutter:<instance>``, of class ``clutter:<class>``: a
    clutter box is never the user's class "box")."""
    object_set = load_object_set(config.source, **config.loader_kwargs())
    if not config.clutter_source:
        return object_set
    other = ObjectSetConfig(source=config.clutter_source, surface_samples=config.surface_samples)
    try:
        clutter = load_object_set(other.source, **other.loader_kwargs()).split("all")
    except (OSError, ValueError) as e:
        raise ValueError(f"objects.clutter_source = {config.clutter_source!r}: {e}") from None
    return dataclasses.replace(object_set, clutter=tuple(
        dataclasses.replace(m, name=f"clutter:{m.name}", class_name=f"clutter:{m.class_name}") for m in clutter))
