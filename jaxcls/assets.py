"""Object sets: the CAD models that scenes are built from and that classification and ICP compare against.

Every model follows the conventions of DESIGN.md: metres, z up, resting on the table (min z = 0), with the
centre of its xy bounding box at x = y = 0, so that a scene places a model by a yaw and a table position.

Sources:
- ``builtin_object_set``: eight procedural household classes in the spirit of LINEMOD (no download):
  ``bottle, bowl, box, can, drill, jug, lamp, mug``. Each class is a parametric family built from closed
  trimesh primitives (revolved profiles, boxes, cylinders, swept tubes); each instance draws its
  parameters from the class's ranges with a NumPy ``Generator`` seeded by (seed, class, split, index).
  Two pairs of classes differ *only* by a part that some viewpoints hide, which is what makes the active
  choice of view matter:

  * ``mug`` = a ``can`` body + a handle. The body is drawn by the same function from the same ranges
    (``_CAN_BODY``) as a can, so a mug seen from the side opposite its handle is a can.
  * ``jug`` = a ``bottle`` body + a handle (``_BOTTLE_BODY``), likewise.

  Handles (and the drill's parts) are closed meshes that overlap the body; the mesh is their
  concatenation (each part is watertight with outward winding, so the whole is too, with interior faces).
  Surface samples are taken only where no other part covers the surface, so they lie on the visible
  boundary of the union.
- ``load_folder``: one subfolder per class holding instance meshes (.obj/.ply/.stl).
- ``load_bop``: the BOP layout LINEMOD ships in (``models/obj_000001.ply`` in mm + ``models_info.json``).

Models are shared (the builtin set is cached): treat their meshes as read-only and ``copy()`` before
transforming one.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import re
import zlib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Literal

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError

MESH_SUFFIXES = (".obj", ".ply", ".stl")
BUILTIN_CLASSES = ("bottle", "bowl", "box", "can", "drill", "jug", "lamp", "mug")
UP_AXES = ("x", "y", "z", "-x", "-y", "-z")

_MIN_EXTENT, _MAX_EXTENT = 0.05, 0.20
_SECTIONS = 36
_TUBE_SECTIONS = 12
_MIN_FACE_AREA = 1e-12
_BOP_FIELDS = ("min_x", "min_y", "min_z", "size_x", "size_y", "size_z")


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
    """

    name: str
    classes: tuple[str, ...]
    train: tuple[ObjectModel, ...]
    test: tuple[ObjectModel, ...]

    def __post_init__(self) -> None:
        if list(self.classes) != sorted(set(self.classes)):
            raise ValueError(f"{self.name}: classes must be sorted and unique, got {self.classes}")
        known = set(self.classes)
        names: set[str] = set()
        for model in self.train + self.test:
            if model.class_name not in known:
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

    def split(self, split: Literal["train", "test", "all"]) -> tuple[ObjectModel, ...]:
        """The models of one split; ``"all"`` is train followed by test."""
        if split == "train":
            return self.train
        if split == "test":
            return self.test
        if split == "all":
            return self.train + self.test
        raise ValueError(f"split must be 'train', 'test' or 'all', got {split!r}")


# ----------------------------------------------------------------------------------------------------------
# Mesh conventions


def _up_rotation(up_axis: str) -> np.ndarray:
    """[3, 3] proper rotation taking the unit vector ``up_axis`` to +z (winding is kept)."""
    if up_axis not in UP_AXES:
        raise ValueError(f"up_axis must be one of {UP_AXES}, got {up_axis!r}")
    up = np.zeros(3)
    up["xyz".index(up_axis[-1])] = -1.0 if up_axis.startswith("-") else 1.0
    first = np.roll(np.abs(up), 1)
    return np.stack([first, np.cross(up, first), up])


def _rest_offset(vertices: np.ndarray) -> np.ndarray:
    """[3] translation that puts min z at 0 and the xy bounding-box centre at the origin."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    return -np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])


def normalise_mesh(mesh: trimesh.Trimesh, scale: float = 1.0, up_axis: str = "z") -> trimesh.Trimesh:
    """A new mesh in the model conventions: scaled to metres, ``up_axis`` rotated to +z, resting on z = 0,
    xy bounding box centred; duplicate vertices merged, zero-area and repeated faces dropped, and a closed
    inside-out mesh turned outward (so face normals, and the samples' normals, point out).

    Raises ValueError for a mesh without faces or with non-finite vertices (callers add the file name).
    """
    if not isinstance(mesh, trimesh.Trimesh):
        raise ValueError(f"expected a triangle mesh, got {type(mesh).__name__}")
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be positive and finite, got {scale}")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if len(faces) == 0 or len(vertices) == 0:
        raise ValueError("mesh has no faces")
    if not np.isfinite(vertices).all():
        bad = int(np.flatnonzero(~np.isfinite(vertices).all(axis=1))[0])
        raise ValueError(f"mesh has a non-finite vertex (index {bad}: {vertices[bad].tolist()})")
    vertices = vertices @ _up_rotation(up_axis).T * scale
    out = trimesh.Trimesh(vertices=vertices, faces=faces, process=True)
    keep = (out.area_faces > _MIN_FACE_AREA) & out.unique_faces()
    out.update_faces(keep)
    out.remove_unreferenced_vertices()
    if len(out.faces) == 0:
        raise ValueError("mesh has no faces of non-zero area")
    if out.is_watertight and out.volume < 0:
        out.invert()
    out.apply_translation(_rest_offset(np.asarray(out.vertices)))
    return out


# ----------------------------------------------------------------------------------------------------------
# Surface sampling


def _winding_numbers(points: np.ndarray, triangles: np.ndarray, chunk: int = 1 << 16) -> np.ndarray:
    """[P] generalised winding numbers of ``points`` [P, 3] w.r.t. the closed surface ``triangles``
    [F, 3, 3]: 1 inside, 0 outside (van Oosterom-Strackee solid angles, no spatial index needed)."""
    corners = [[np.ascontiguousarray(triangles[:, v, i]) for i in range(3)] for v in range(3)]
    out = np.zeros(len(points))
    step = max(1, chunk // max(1, len(triangles)))
    for start in range(0, len(points), step):
        p = points[start:start + step]
        (ax, ay, az), (bx, by, bz), (cx, cy, cz) = (
            [corner[i][None, :] - p[:, i, None] for i in range(3)] for corner in corners)
        la, lb, lc = (np.sqrt(x * x + y * y + z * z)
                      for x, y, z in ((ax, ay, az), (bx, by, bz), (cx, cy, cz)))
        det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
        den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (bx * cx + by * cy + bz * cz) * la
               + (cx * ax + cy * ay + cz * az) * lb)
        out[start:start + step] = np.arctan2(det, den).sum(axis=1) / (2 * np.pi)
    return out


def _sample_faces(mesh: trimesh.Trimesh, count: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """Area-weighted uniform samples: points [count, 3] f64 and the index of the face each lies on."""
    cumulative = np.cumsum(mesh.area_faces)
    face = np.minimum(np.searchsorted(cumulative, rng.random(count) * cumulative[-1], side="right"),
                      len(cumulative) - 1)
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    tri = np.asarray(mesh.triangles)[face]
    points = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
    return points, face


def _surface_samples(mesh: trimesh.Trimesh, count: int, rng: np.random.Generator,
                     face_part: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Uniform samples of the mesh's outer surface: points [count, 3] f32, normals [count, 3] f32.

    With ``face_part`` ([F] int, one closed part per id) samples of one part that lie inside another part
    are rejected, so that the samples cover only the boundary of the union.
    """
    if count <= 0:
        raise ValueError(f"surface_samples must be positive, got {count}")
    normals_all = np.asarray(mesh.face_normals)
    if face_part is None or face_part.max() == 0:
        points, face = _sample_faces(mesh, count, rng)
        return points.astype(np.float32), normals_all[face].astype(np.float32)
    triangles = np.asarray(mesh.triangles)
    parts = [triangles[face_part == p] for p in range(int(face_part.max()) + 1)]
    boxes = [(t.reshape(-1, 3).min(axis=0), t.reshape(-1, 3).max(axis=0)) for t in parts]
    kept_points, kept_faces, total = [], [], 0
    while total < count:
        points, face = _sample_faces(mesh, count + count // 4 + 16, rng)
        keep = np.ones(len(points), dtype=bool)
        for p, (lo, hi) in enumerate(boxes):
            near = np.flatnonzero((face_part[face] != p) & np.all((points >= lo) & (points <= hi), axis=1))
            if len(near):
                keep[near[_winding_numbers(points[near], parts[p]) > 0.5]] = False
        kept_points.append(points[keep])
        kept_faces.append(face[keep])
        total += int(keep.sum())
    points = np.concatenate(kept_points)[:count]
    face = np.concatenate(kept_faces)[:count]
    return points.astype(np.float32), normals_all[face].astype(np.float32)


def _sample_rng(name: str) -> np.random.Generator:
    """A generator fixed by the model name, so loaded models sample the same points on every run."""
    return np.random.default_rng(zlib.crc32(name.encode()))


# ----------------------------------------------------------------------------------------------------------
# Procedural parts (metres; each part closed with outward winding)

Ranges = Mapping[str, tuple[float, float]]

_CAN_BODY: Ranges = {
    "radius": (0.028, 0.045), "height": (0.07, 0.16), "bevel": (0.002, 0.004), "recess": (0.0015, 0.004),
}
_BOTTLE_BODY: Ranges = {
    "radius": (0.024, 0.038), "height": (0.13, 0.20), "bevel": (0.002, 0.005),
    "neck_ratio": (0.3, 0.45), "shoulder_frac": (0.12, 0.22), "neck_frac": (0.08, 0.15),
    "cap_height": (0.012, 0.02), "cap_lip": (0.001, 0.003),
}
_MUG_HANDLE: Ranges = {
    "tube": (0.004, 0.006), "reach": (0.016, 0.03), "span_frac": (0.45, 0.6), "centre_frac": (0.45, 0.55),
    "corner_frac": (0.55, 0.95),
}
_JUG_HANDLE: Ranges = {
    "tube": (0.005, 0.008), "reach": (0.02, 0.035), "span_frac": (0.55, 0.85), "top_frac": (0.85, 1.0),
    "corner_frac": (0.5, 0.9),
}
_BOWL: Ranges = {
    "radius": (0.05, 0.085), "height": (0.04, 0.075), "foot_ratio": (0.35, 0.5),
    "foot_height": (0.004, 0.008), "wall": (0.003, 0.006), "bottom": (0.004, 0.008),
}
_BOX: Ranges = {"size_x": (0.05, 0.18), "size_y": (0.03, 0.09), "size_z": (0.04, 0.18)}
_DRILL: Ranges = {
    "base_x": (0.06, 0.09), "base_y": (0.05, 0.075), "base_z": (0.025, 0.04),
    "grip_x": (0.025, 0.035), "grip_y": (0.022, 0.03), "grip_len": (0.06, 0.085), "grip_tilt": (0.1, 0.3),
    "body_radius": (0.02, 0.03), "body_len": (0.09, 0.12), "body_back": (0.01, 0.025),
    "chuck_radius": (0.01, 0.016), "chuck_len": (0.02, 0.03), "bit_radius": (0.002, 0.004),
    "bit_len": (0.015, 0.03),
}
_LAMP: Ranges = {
    "height": (0.13, 0.20), "base_radius": (0.035, 0.055), "base_height": (0.008, 0.018),
    "stem_radius": (0.005, 0.009), "shade_height": (0.04, 0.07), "shade_radius": (0.04, 0.07),
    "shade_top_ratio": (0.45, 0.75),
}


def _draw(rng: np.random.Generator, ranges: Ranges) -> dict[str, float]:
    """One uniform draw per parameter, in the ranges' key order (so the stream is reproducible)."""
    return {key: float(rng.uniform(lo, hi)) for key, (lo, hi) in ranges.items()}


def _revolve(profile: Sequence[tuple[float, float]], sections: int = _SECTIONS) -> trimesh.Trimesh:
    """Closed solid of revolution about z of a (radius, z) profile that starts and ends on the axis and runs
    counter-clockwise (out along the bottom, up, back along the top)."""
    mesh = trimesh.creation.revolve(np.asarray(profile, dtype=np.float64), sections=sections)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def _box(extents: Sequence[float], centre: Sequence[float], yaw_pitch: float = 0.0) -> trimesh.Trimesh:
    """Box of ``extents`` [3] centred at ``centre``, rotated by ``yaw_pitch`` rad about y."""
    transform = trimesh.transformations.rotation_matrix(yaw_pitch, [0, 1, 0])
    transform[:3, 3] = centre
    return trimesh.creation.box(extents=extents, transform=transform)


def _x_cylinder(radius: float, x0: float, x1: float, z: float, sections: int = 24) -> trimesh.Trimesh:
    """Closed cylinder along x from ``x0`` to ``x1`` with its axis at height ``z``."""
    transform = trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])
    transform[:3, 3] = [(x0 + x1) / 2, 0.0, z]
    return trimesh.creation.cylinder(radius=radius, height=x1 - x0, sections=sections, transform=transform)


def _tube(points: np.ndarray, tangents: np.ndarray, radius: float) -> trimesh.Trimesh:
    """Closed tube of circular section swept along a path in the xz-plane; points, tangents: [N, 3]."""
    binormal = np.array([0.0, 1.0, 0.0])
    tangents = tangents / np.linalg.norm(tangents, axis=1, keepdims=True)
    normal = np.cross(binormal, tangents)
    phi = np.linspace(0, 2 * np.pi, _TUBE_SECTIONS, endpoint=False)
    ring = (np.cos(phi)[None, :, None] * normal[:, None, :] + np.sin(phi)[None, :, None] * binormal)
    n, m = len(points), _TUBE_SECTIONS
    vertices = np.concatenate([(points[:, None, :] + radius * ring).reshape(-1, 3), points[[0, -1]]])
    i, k = np.meshgrid(np.arange(n - 1), np.arange(m), indexing="ij")
    a, b = i * m + k, i * m + (k + 1) % m
    c, d = b + m, a + m
    side = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)]).reshape(-1, 3)
    ks = np.arange(m)
    start = np.stack([np.full(m, n * m), (ks + 1) % m, ks], -1)
    end = np.stack([np.full(m, n * m + 1), (n - 1) * m + ks, (n - 1) * m + (ks + 1) % m], -1)
    return trimesh.Trimesh(vertices=vertices, faces=np.concatenate([side, start, end]), process=True)


def _handle(body_radius: float, z_bot: float, z_top: float, tube: float, reach: float,
            corner_frac: float) -> trimesh.Trimesh:
    """A D-shaped handle on the +x side of a vertical body of radius ``body_radius``: out at ``z_top``,
    down at ``body_radius + reach``, back in at ``z_bot``; both ends sunk 1.5 tube radii into the body."""
    x_in, x_out = body_radius - 1.5 * tube, body_radius + reach
    corner = max(1.6 * tube, corner_frac * min(reach, (z_top - z_bot) / 2))
    arc = np.linspace(0, np.pi / 2, 7)
    pts: list[np.ndarray] = [np.array([x_in, 0, z_top])]
    tans: list[np.ndarray] = [np.array([1.0, 0, 0])]
    for centre_z, sign in ((z_top - corner, 1.0), (z_bot + corner, -1.0)):
        angles = arc if sign > 0 else arc[::-1]
        for t in angles:
            s, c = np.sin(t), np.cos(t)
            pts.append(np.array([x_out - corner + corner * s, 0, centre_z + sign * corner * c]))
            tans.append(np.array([sign * c, 0, -s]))
    pts.append(np.array([x_in, 0, z_bot]))
    tans.append(np.array([-1.0, 0, 0]))
    points, tangents = np.array(pts), np.array(tans)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-9])
    return _tube(points[keep], tangents[keep], tube)


def _can_body(p: Mapping[str, float]) -> trimesh.Trimesh:
    r, h, b, d = p["radius"], p["height"], p["bevel"], p["recess"]
    return _revolve([(0, 0), (r - b, 0), (r, b), (r, h - b), (r - b, h), (r - 2 * b, h - d), (0, h - d)])


def _bottle_body(p: Mapping[str, float]) -> tuple[trimesh.Trimesh, float]:
    """The bottle solid and the height where its straight body ends (the shoulder starts)."""
    r, h, b = p["radius"], p["height"], p["bevel"]
    neck = max(0.009, p["neck_ratio"] * r)
    shoulder, neck_len, cap = p["shoulder_frac"] * h, p["neck_frac"] * h, p["cap_height"]
    z_body = h - cap - neck_len - shoulder
    s = np.linspace(0, 1, 7)[1:]
    curve = [(r - (r - neck) * (1 - np.cos(np.pi * t)) / 2, z_body + t * shoulder) for t in s]
    z_cap = z_body + shoulder + neck_len
    cap_r = neck + p["cap_lip"]
    profile = [(0, 0), (r - b, 0), (r, b), (r, z_body), *curve, (neck, z_cap), (cap_r, z_cap), (cap_r, h),
               (0, h)]
    return _revolve(profile), z_body


def _can(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    return [_can_body(_draw(rng, _CAN_BODY))]


def _mug(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    body = _draw(rng, _CAN_BODY)
    q = _draw(rng, _MUG_HANDLE)
    h = body["height"]
    z_mid, half = q["centre_frac"] * h, q["span_frac"] * h / 2
    return [_can_body(body),
            _handle(body["radius"], z_mid - half, z_mid + half, q["tube"], q["reach"], q["corner_frac"])]


def _bottle(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    return [_bottle_body(_draw(rng, _BOTTLE_BODY))[0]]


def _jug(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    body_p = _draw(rng, _BOTTLE_BODY)
    q = _draw(rng, _JUG_HANDLE)
    body, z_body = _bottle_body(body_p)
    lo, hi = body_p["bevel"] + q["tube"] + 0.002, z_body - q["tube"] - 0.002
    z_top = lo + q["top_frac"] * (hi - lo)
    z_bot = z_top - q["span_frac"] * (z_top - lo)
    return [body, _handle(body_p["radius"], z_bot, z_top, q["tube"], q["reach"], q["corner_frac"])]


def _bowl(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    p = _draw(rng, _BOWL)
    r, h, foot, hf, w = p["radius"], p["height"], p["foot_ratio"] * p["radius"], p["foot_height"], p["wall"]
    z_in = hf + p["bottom"]
    alpha = np.linspace(0, np.pi / 2, 9)
    outer = [(foot + (r - foot) * np.sin(a), hf + (h - hf) * (1 - np.cos(a))) for a in alpha]
    inner = [((r - w) * np.sin(a), z_in + (h - z_in) * (1 - np.cos(a))) for a in alpha[::-1]]
    return [_revolve([(0, 0), (foot, 0), *outer, *inner])]


def _box_class(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    p = _draw(rng, _BOX)
    size = [p["size_x"], p["size_y"], p["size_z"]]
    return [_box(size, [0, 0, size[2] / 2])]


def _drill(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Battery base on the table, a grip tilted back, the motor housing along x, chuck and bit in front."""
    p = _draw(rng, _DRILL)
    base = _box([p["base_x"], p["base_y"], p["base_z"]], [0, 0, p["base_z"] / 2])
    tilt, length = p["grip_tilt"], p["grip_len"]
    bottom = np.array([0.0, 0.0, p["base_z"] - 0.008])
    direction = np.array([-np.sin(tilt), 0.0, np.cos(tilt)])
    top = bottom + length * direction
    grip = _box([p["grip_x"], p["grip_y"], length], bottom + length / 2 * direction, -tilt)
    rb = p["body_radius"]
    z_axis = top[2] + 0.2 * rb
    x_back = top[0] - p["grip_x"] / 2 - p["body_back"]
    x_front = x_back + p["body_len"]
    housing = _x_cylinder(rb, x_back, x_front, z_axis)
    chuck_end = x_front - 0.004 + p["chuck_len"]
    chuck = _x_cylinder(p["chuck_radius"], x_front - 0.004, chuck_end, z_axis)
    bit = _x_cylinder(p["bit_radius"], chuck_end - 0.003, chuck_end - 0.003 + p["bit_len"], z_axis, 12)
    return [base, grip, housing, chuck, bit]


def _lamp(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    p = _draw(rng, _LAMP)
    h, rb, hb, rs = p["height"], p["base_radius"], p["base_height"], p["stem_radius"]
    z_shade = h - p["shade_height"]
    shade_bottom, shade_top = p["shade_radius"], p["shade_radius"] * p["shade_top_ratio"]
    profile = [(0, 0), (rb, 0), (rb, 0.6 * hb), (0.85 * rb, hb), (rs, hb), (rs, z_shade),
               (shade_bottom, z_shade), (shade_top, h), (0, h)]
    return [_revolve(profile)]


_FAMILIES: dict[str, Callable[[np.random.Generator], list[trimesh.Trimesh]]] = {
    "bottle": _bottle, "bowl": _bowl, "box": _box_class, "can": _can, "drill": _drill, "jug": _jug,
    "lamp": _lamp, "mug": _mug,
}


def _instance_parts(class_name: str, rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """The closed parts of one instance, body first (a mug's body is exactly a can drawn from ``rng``)."""
    return _FAMILIES[class_name](rng)


def _assemble(parts: Sequence[trimesh.Trimesh]) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Concatenate parts in the rest pose; returns the mesh and the part index of each face [F]."""
    offset = _rest_offset(np.concatenate([np.asarray(p.vertices) for p in parts]))
    vertices, faces, face_part, base = [], [], [], 0
    for i, part in enumerate(parts):
        vertices.append(np.asarray(part.vertices) + offset)
        faces.append(np.asarray(part.faces) + base)
        face_part.append(np.full(len(part.faces), i))
        base += len(part.vertices)
    mesh = trimesh.Trimesh(vertices=np.concatenate(vertices), faces=np.concatenate(faces), process=False)
    return mesh, np.concatenate(face_part)


def _builtin_model(class_name: str, split: int, index: int, seed: int, surface_samples: int,
                   name: str) -> ObjectModel:
    """One instance; its generators depend only on (seed, class, split, index), so train and test use
    disjoint seeds and an instance does not change when the number of instances per class does."""
    sequence = np.random.SeedSequence([seed, zlib.crc32(class_name.encode()), split, index])
    shape_seq, sample_seq = sequence.spawn(2)
    mesh, face_part = _assemble(_instance_parts(class_name, np.random.default_rng(shape_seq)))
    extent = float(np.ptp(mesh.vertices, axis=0).max())
    if not _MIN_EXTENT <= extent <= _MAX_EXTENT:
        raise AssertionError(f"{name}: largest extent {extent:.3f} m outside [{_MIN_EXTENT}, {_MAX_EXTENT}]")
    points, normals = _surface_samples(mesh, surface_samples, np.random.default_rng(sample_seq), face_part)
    return ObjectModel(name, class_name, mesh, points, normals)


@functools.lru_cache(maxsize=8)
def _builtin_cached(seed: int, train_per_class: int, test_per_class: int, surface_samples: int) -> ObjectSet:
    train, test = [], []
    for class_name in BUILTIN_CLASSES:
        for i in range(train_per_class):
            train.append(_builtin_model(class_name, 0, i, seed, surface_samples, f"{class_name}_{i:03d}"))
        for i in range(test_per_class):
            test.append(_builtin_model(class_name, 1, i, seed, surface_samples, f"{class_name}_test_{i:03d}"))
    return ObjectSet(f"builtin_seed{seed}", BUILTIN_CLASSES, tuple(train), tuple(test))


def builtin_object_set(seed: int = 0, train_per_class: int = 8, test_per_class: int = 4,
                       surface_samples: int = 2048) -> ObjectSet:
    """The procedural set (see the module docstring), cached: the same arguments return the same object.

    Train instances are named ``mug_000``..., held-out test instances ``mug_test_000``...
    """
    if seed < 0 or train_per_class < 0 or test_per_class < 0:
        raise ValueError("seed, train_per_class and test_per_class must be non-negative")
    return _builtin_cached(int(seed), int(train_per_class), int(test_per_class), int(surface_samples))


# ----------------------------------------------------------------------------------------------------------
# User models


def _read_mesh(path: Path) -> trimesh.Trimesh:
    """Load one mesh file as-is (no processing, so that bad vertices are seen), with errors naming it."""
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as error:
        raise ValueError(f"{path}: cannot read as a mesh ({type(error).__name__}: {error})") from error
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path}: mesh has no faces")
    return mesh


def _model_from_file(path: Path, name: str, class_name: str, scale: float, up_axis: str,
                     surface_samples: int) -> ObjectModel:
    raw = _read_mesh(path)
    try:
        mesh = normalise_mesh(raw, scale=scale, up_axis=up_axis)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from error
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
    Instance names are ``<class>_<stem>``.
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
    """Largest distance between two vertices (BOP's ``diameter``), via the convex hull."""
    try:
        points = vertices[ConvexHull(vertices).vertices]
    except (QhullError, ValueError):
        points = vertices
    best = 0.0
    for start in range(0, len(points), 512):
        diff = points[start:start + 512, None, :] - points[None, :, :]
        best = max(best, float(np.sqrt((diff**2).sum(-1)).max()))
    return best


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
    lo, size = vertices.min(axis=0), np.ptp(vertices, axis=0)
    measured = {f"{kind}_{a}": float(v[i]) for kind, v in (("min", lo), ("size", size))
                for i, a in enumerate("xyz")}
    tolerance = {f"{kind}_{a}": max(1.0, 0.01 * abs(values[f"size_{a}"]))
                 for kind in ("min", "size") for a in "xyz"}
    if "diameter" in values:
        measured["diameter"] = _max_distance(vertices)
        tolerance["diameter"] = max(1.0, 0.01 * abs(values["diameter"]))
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


def load_object_set(source: str, **kwargs) -> ObjectSet:
    """``"builtin"`` -> ``builtin_object_set(**kwargs)``; a folder with ``models/models_info.json`` (or a
    ``models`` folder holding it) -> ``load_bop``; any other folder -> ``load_folder``."""
    if source == "builtin":
        return builtin_object_set(**kwargs)
    root = Path(source)
    if not root.is_dir():
        raise FileNotFoundError(f"object set source is neither 'builtin' nor a folder: {source}")
    if _is_bop(root):
        return load_bop(root, **kwargs)
    return load_folder(root, **kwargs)


def _is_bop(root: Path) -> bool:
    return (root / "models" / "models_info.json").is_file() or (root / "models_info.json").is_file()


@dataclasses.dataclass(frozen=True)
class ObjectSetConfig:
    """Which object set a run uses: the ``objects:`` section of a YAML config, recorded in scene JSON.

    source: ``"builtin"``, a BOP folder or a class-folder layout (``load_object_set``). Fields that the
    chosen source does not use must keep their defaults, so that a setting is never silently ignored.
    """

    source: str = "builtin"
    seed: int = 0
    train_per_class: int = 8
    test_per_class: int = 4
    surface_samples: int = 2048
    test_fraction: float = 0.0
    scale: float = 1.0
    up_axis: str = "z"

    def loader_kwargs(self) -> dict:
        """Keyword arguments of the loader that ``load_object_set(self.source, ...)`` dispatches to."""
        if self.source == "builtin":
            used = ("seed", "train_per_class", "test_per_class", "surface_samples")
        elif _is_bop(Path(self.source)):
            used = ("test_fraction", "surface_samples", "up_axis")
        else:
            used = ("test_fraction", "surface_samples", "scale", "up_axis")
        default = ObjectSetConfig()
        unused = [f.name for f in dataclasses.fields(self)
                  if f.name not in (*used, "source") and getattr(self, f.name) != getattr(default, f.name)]
        if unused:
            raise ValueError(f"objects: {unused} do not apply to source {self.source!r}")
        return {name: getattr(self, name) for name in used}


def object_set_from_config(config: ObjectSetConfig) -> ObjectSet:
    """The object set a config names (the builtin one comes from the cache)."""
    return load_object_set(config.source, **config.loader_kwargs())
