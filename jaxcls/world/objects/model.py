"""The model types: one object instance in its canonical frame, and a set of them split into classes and
train/test instances (see the package docstring for the conventions)."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Literal

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, cKDTree


@dataclasses.dataclass(frozen=True, eq=False)
class ObjectModel:
    """One object instance in its canonical model frame.

    ``eq=False``: models compare and hash by identity, so they can key dicts and caches.

    mesh: metres, z up, min z = 0, xy bounding-box centre at the origin.
    surface_points: [S, 3] f32, metres, area-uniform samples of the visible surface (model frame).
    surface_normals: [S, 3] f32, unit outward normals of those samples.
    """

    name: str
    class_name: str
    mesh: trimesh.Trimesh
    surface_points: np.ndarray
    surface_normals: np.ndarray

    def __post_init__(self) -> None:
        for field in ("surface_points", "surface_normals"):
            value = np.array(getattr(self, field), dtype=np.float32)
            if value.ndim != 2 or value.shape[1] != 3:
                raise ValueError(f"{self.name}: {field} must be [S, 3], got {value.shape}")
            value.setflags(write=False)
            object.__setattr__(self, field, value)
        if self.surface_points.shape != self.surface_normals.shape:
            raise ValueError(f"{self.name}: surface_points and surface_normals differ in shape")

    @property
    def bounds(self) -> np.ndarray:
        """[2, 3] f64, metres: min and max corners of the axis-aligned bounding cuboid (model frame)."""
        return np.array(self.mesh.bounds, dtype=np.float64)

    @property
    def cuboid_corners(self) -> np.ndarray:
        """[8, 3] f64, metres: corner k takes x, y, z from ``bounds[k >> 2 & 1, 0]``, ``[k >> 1 & 1, 1]``,
        ``[k & 1, 2]`` (itertools.product order), so corners k and k ^ 1 share an edge along z."""
        b = self.bounds
        bits = (np.arange(8)[:, None] >> np.array([2, 1, 0])) & 1
        return b[bits, np.arange(3)]

    @functools.cached_property
    def yaw_symmetry(self) -> int:
        """Order of the model's rotational symmetry about its z axis: 0 = continuous (a can, a bowl), k >= 2
        = unchanged by turns of 2 pi / k (a box: 2), 1 = none (a mug, a drill). Read from the surface
        samples: the model turned by the angle matches itself as closely as two random halves of its own
        samples match each other (98th percentile of nearest-sample distances)."""
        points = np.asarray(self.surface_points, np.float64)
        half = len(points) // 2
        a, tree = points[:half], cKDTree(points[half:])
        baseline = np.percentile(tree.query(a)[0], 98)
        tolerance = 1.5 * baseline + 5e-4

        def matches(angle: float) -> bool:
            c, s = np.cos(angle), np.sin(angle)
            turned = a @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
            return np.percentile(tree.query(turned)[0], 98) <= tolerance

        if all(matches(angle) for angle in (0.61, 1.73, 2.9)):  # turns no finite order below 11 allows
            return 0
        return next((k for k in (6, 4, 3, 2) if all(matches(2 * np.pi * j / k) for j in range(1, k))), 1)

    def footprint(self) -> np.ndarray:
        """[K, 2] f64, metres: counter-clockwise convex hull of the vertices projected on xy.

        Scenes keep footprints of neighbouring objects disjoint.
        """
        xy = np.asarray(self.mesh.vertices)[:, :2]
        hull = ConvexHull(xy)
        return xy[hull.vertices].astype(np.float64)


@dataclasses.dataclass(frozen=True, eq=False)
class ObjectSet:
    """Models grouped into classes and a train/test split of instances.

    classes: sorted class names; a class's index everywhere (labels, logits) is its position here.
    clutter: instances of another set that scenes may place as clutter (``ObjectSetConfig.clutter_source``):
    their classes are not among ``classes`` (``label`` gives them -1) and no split holds them.
    """

    name: str
    classes: tuple[str, ...]
    train: tuple[ObjectModel, ...]
    test: tuple[ObjectModel, ...]
    clutter: tuple[ObjectModel, ...] = ()

    def __post_init__(self) -> None:
        if list(self.classes) != sorted(set(self.classes)):
            raise ValueError(f"{self.name}: classes must be sorted and unique, got {self.classes}")
        known = set(self.classes)
        names: set[str] = set()
        for model in self.train + self.test + self.clutter:
            if model.class_name not in known and model not in self.clutter:
                raise ValueError(f"{self.name}: model {model.name} has unknown class {model.class_name!r}")
            if model.name in names:
                raise ValueError(f"{self.name}: duplicate model name {model.name!r}")
            names.add(model.name)

    def class_index(self, class_name: str) -> int:
        """Position of ``class_name`` in ``classes``: the label used by every module."""
        try:
            return self.classes.index(class_name)
        except ValueError:
            raise KeyError(f"{self.name}: unknown class {class_name!r}; classes are {self.classes}") from None

    def label(self, class_name: str) -> int:
        """``class_index``, or -1 for a class outside the set (a clutter instance of another set)."""
        return self.classes.index(class_name) if class_name in self.classes else -1

    def split(self, split: Literal["train", "test", "all"]) -> tuple[ObjectModel, ...]:
        """The models of one split; ``"all"`` is train followed by test."""
        if split == "train":
            return self.train
        if split == "test":
            return self.test
        if split == "all":
            return self.train + self.test
        raise ValueError(f"split must be 'train', 'test' or 'all', got {split!r}")


def kept_on_disk(kind: str, arguments: tuple, build: Callable[[], ObjectSet]) -> ObjectSet:
    """``build()`` (a procedural set: meshes and surface samples made from seeds, no clutter), or the same set read
    back from where ``jaxcls.compile_cache`` keeps host work once ``enable`` ran (``cached_arrays``, under
    ``kind``), keyed by ``arguments`` (the builder's), jaxcls's source and the NumPy and trimesh versions: a warm
    process does not make the meshes again (the builtin set on the 2-core CPU: 0.45-0.5 s -> ~0.06 s; on the
    way to a warm Table 1 run's first call). The meshes come back as ``trimesh.Trimesh(process=False)`` of the same
    vertices and faces, the samples and names the same."""
    from jaxcls import compile_cache

    def pack() -> dict[str, np.ndarray]:
        made = build()
        if made.clutter:
            raise ValueError(f"kept_on_disk: {made.name} has clutter; only a procedural set's own models are kept")
        models = made.train + made.test

        def joined(arrays: list, width: int, dtype: type) -> np.ndarray:  # (none: an empty set asked for)
            return np.concatenate(arrays) if arrays else np.zeros((0, width), dtype)

        return {"set": np.array([made.name]), "classes": np.array(made.classes),
                "names": np.array([m.name for m in models]), "model_classes": np.array([m.class_name for m in models]),
                "train": np.array([i < len(made.train) for i in range(len(models))]),
                "vertex_counts": np.array([len(m.mesh.vertices) for m in models]),
                "face_counts": np.array([len(m.mesh.faces) for m in models]),
                "vertices": joined([np.asarray(m.mesh.vertices) for m in models], 3, np.float64),
                "faces": joined([np.asarray(m.mesh.faces) for m in models], 3, np.int64),
                "sample_counts": np.array([len(m.surface_points) for m in models]),
                "points": joined([m.surface_points for m in models], 3, np.float32),
                "normals": joined([m.surface_normals for m in models], 3, np.float32)}

    key = repr((kind, arguments, compile_cache.code_digest(), np.__version__, trimesh.__version__)).encode()
    kept = compile_cache.cached_arrays(f"object_sets/{kind}", key, pack)
    n = len(kept["names"])

    def each(name: str, counts: str) -> list[np.ndarray]:  # (the models' pieces of a joined array)
        return np.split(kept[name], np.cumsum(kept[counts])[:-1])[:n]

    parts = zip(kept["names"], kept["model_classes"], each("vertices", "vertex_counts"), each("faces", "face_counts"),
                each("points", "sample_counts"), each("normals", "sample_counts"), strict=True)
    models = [ObjectModel(str(name), str(class_name), trimesh.Trimesh(vertices=v, faces=f, process=False), points,
                          normals) for name, class_name, v, f, points, normals in parts]
    train = tuple(m for m, t in zip(models, kept["train"], strict=True) if t)
    test = tuple(m for m, t in zip(models, kept["train"], strict=True) if not t)
    return ObjectSet(str(kept["set"][0]), tuple(str(c) for c in kept["classes"]), train, test)
