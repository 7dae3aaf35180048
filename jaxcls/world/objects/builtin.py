"""The builtin object set: eight procedural household classes built with trimesh from seeds (no download).

See the package docstring for the classes and how ``mug``/``can`` and ``jug``/``bottle`` pair up.
"""

from __future__ import annotations

import functools
import zlib
from collections.abc import Callable, Mapping, Sequence

import numpy as np
import trimesh

from jaxcls.world.objects.mesh import _rest_offset, _surface_samples
from jaxcls.world.objects.model import ObjectModel, ObjectSet, kept_on_disk

BUILTIN_CLASSES = ("bottle", "bowl", "box", "can", "drill", "jug", "lamp", "mug")

_MIN_EXTENT, _MAX_EXTENT = 0.05, 0.20
_SECTIONS = 36
_TUBE_SECTIONS = 12


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
            corner_frac: float, sink: float = 1.5) -> trimesh.Trimesh:
    """A D-shaped handle on the +x side of a vertical body of radius ``body_radius``: out at ``z_top``,
    down at ``body_radius + reach``, back in at ``z_bot``; both ends sunk ``sink`` tube radii into the body
    (1.5 into a solid body; a hollow one's thin wall takes less, so that the ends stay inside the wall)."""
    x_in, x_out = body_radius - sink * tube, body_radius + reach
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
    return [_bowl_body(_draw(rng, _BOWL))]


def _bowl_walls(p: Mapping[str, float]) -> tuple[list[tuple[float, float]], list[tuple[float, float]]]:
    """The (radius, z) polylines (metres) of the outer and the inner wall of the bowl of the ``_BOWL``
    parameters ``p``, both from the bottom up: quarter ellipses from the foot ring (radius
    ``foot_ratio * radius`` at ``foot_height``) and from the axis at ``foot_height + bottom`` out to the flat
    rim, ``wall`` wide, at ``height``."""
    r, h, foot, hf, w = p["radius"], p["height"], p["foot_ratio"] * p["radius"], p["foot_height"], p["wall"]
    z_in = hf + p["bottom"]
    alpha = np.linspace(0, np.pi / 2, 9)
    outer = [(foot + (r - foot) * np.sin(a), hf + (h - hf) * (1 - np.cos(a))) for a in alpha]
    inner = [((r - w) * np.sin(a), z_in + (h - z_in) * (1 - np.cos(a))) for a in alpha]
    return outer, inner


def _bowl_body(p: Mapping[str, float]) -> trimesh.Trimesh:
    """The bowl solid of the ``_BOWL`` parameters ``p`` (``_bowl_walls``)."""
    outer, inner = _bowl_walls(p)
    return _revolve([(0, 0), (p["foot_ratio"] * p["radius"], 0), *outer, *inner[::-1]])


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
    return _procedural_model(class_name, _instance_parts, sequence, surface_samples, name)


def _procedural_model(class_name: str, instance_parts: Callable[[str, np.random.Generator], list[trimesh.Trimesh]],
                      sequence: np.random.SeedSequence, surface_samples: int, name: str) -> ObjectModel:
    """One procedural instance named ``name``: ``instance_parts(class_name, rng)`` assembled, its shape and its
    surface samples from their own generators spawned from ``sequence`` (so the samples' count does not change
    the shape); its largest extent checked against [_MIN_EXTENT, _MAX_EXTENT] m."""
    shape_seq, sample_seq = sequence.spawn(2)
    mesh, face_part = _assemble(instance_parts(class_name, np.random.default_rng(shape_seq)))
    extent = float(np.ptp(mesh.vertices, axis=0).max())
    if not _MIN_EXTENT <= extent <= _MAX_EXTENT:
        raise AssertionError(f"{name}: largest extent {extent:.3f} m outside [{_MIN_EXTENT}, {_MAX_EXTENT}]")
    points, normals = _surface_samples(mesh, surface_samples, np.random.default_rng(sample_seq), face_part)
    return ObjectModel(name, class_name, mesh, points, normals)


@functools.lru_cache(maxsize=8)
def _builtin_cached(seed: int, train_per_class: int, test_per_class: int, surface_samples: int) -> ObjectSet:
    def build() -> ObjectSet:
        train, test = [], []
        for class_name in BUILTIN_CLASSES:
            for i in range(train_per_class):
                train.append(_builtin_model(class_name, 0, i, seed, surface_samples, f"{class_name}_{i:03d}"))
            for i in range(test_per_class):
                test.append(_builtin_model(class_name, 1, i, seed, surface_samples, f"{class_name}_test_{i:03d}"))
        return ObjectSet(f"builtin_seed{seed}", BUILTIN_CLASSES, tuple(train), tuple(test))

    return kept_on_disk("builtin", (seed, train_per_class, test_per_class, surface_samples), build)


def builtin_object_set(seed: int = 0, train_per_class: int = 8, test_per_class: int = 4,
                       surface_samples: int = 2048) -> ObjectSet:
    """The procedural set (see the ``jaxcls.world.objects`` docstring), cached: the same arguments return
    the same object.

    Train instances are named ``mug_000``..., held-out test instances ``mug_test_000``...
    """
    if seed < 0 or train_per_class < 0 or test_per_class < 0:
        raise ValueError("seed, train_per_class and test_per_class must be non-negative")
    return _builtin_cached(int(seed), int(train_per_class), int(test_per_class), int(surface_samples))

