"""Mesh conventions and surface sampling: what every object set (builtin, class folder, BOP) goes through.

``normalise_mesh`` puts a mesh in the model conventions of the package docstring (metres, z up, resting on
z = 0, xy bounding box centred); ``_surface_samples`` draws the area-uniform samples of its visible surface
that classification and ICP compare against.
"""

from __future__ import annotations

import math
import zlib
from pathlib import Path

import numpy as np
import trimesh

MESH_SUFFIXES = (".obj", ".ply", ".stl")
UP_AXES = ("x", "y", "z", "-x", "-y", "-z")

_MIN_FACE_AREA = 1e-12


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


def _read_mesh(path: Path) -> trimesh.Trimesh:
    """Load one mesh file as-is (no processing, so that bad vertices are seen), with errors naming it."""
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as error:
        raise ValueError(f"{path}: cannot read as a mesh ({type(error).__name__}: {error})") from error
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path}: mesh has no faces")
    return mesh


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
    """Area-weighted uniform samples: points [count, 3] f64 and the index of the face each lies on.

    Not ``trimesh.sample.sample_surface``: its random stream differs from this one (it draws the two
    barycentric numbers of each sample interleaved, and picks faces with ``searchsorted(side="left")``), and
    the samples must stay bit-identical, since the shipped PointNet weights and cached training clouds were
    made from them.
    """
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
