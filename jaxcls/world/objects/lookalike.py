"""The lookalike object set: nine procedural classes in two families of lookalikes (issue 35's hard protocol).

Every class of a family is one body plus a subset of that family's parts, so that two classes can differ in
exactly one part, and that part is hidden from some viewing directions (behind the body, below the rim, or
deep inside):

=========== ====== ============== ==========================================================================
class       body   parts          seen as
=========== ====== ============== ==========================================================================
cup         cup    --             a straight open cup (radius 3-4.5 cm, 7-12 cm tall, wall 3-5 mm)
mug         cup    handle         cup + a D handle on one side (builtin's ``_handle`` and ``_MUG_HANDLE``)
canister    cup    lid            cup + a lid 2-5 mm below the rim (a plug filling the cup: a can)
stein       cup    handle, lid    mug + the lid
infuser_cup cup    insert         cup + a round insert standing on its bottom, 30-50 % of the inside deep
bowl        bowl   --             builtin's bowl (``_bowl_body``; radius 5-8 cm, 4-7.5 cm tall, wall 5-8 mm)
spout_bowl  bowl   spout          bowl + a pouring spout on one side, just below the rim
tube_pan    bowl   tube           bowl + a central tube inside, 45-75 % of the inside depth tall
lug_bowl    bowl   lug            bowl + a block on one side of its lower wall, under the rim's overhang
=========== ====== ============== ==========================================================================

The lookalike pairs (``lookalike_pairs``): cup/mug, cup/canister, cup/infuser_cup, mug/stein, canister/stein
(the handle, the lid or the insert), bowl/spout_bowl, bowl/tube_pan, bowl/lug_bowl. A handle, a spout or a lug
stands on one side of the body, which hides it from the other side (the lug, under the bowl's wide rim, also
from the views steeply above). The lid is seen from above the rim; the tube only from high enough to look over
the near wall, the insert at the bottom of a deep narrow cup from higher still. RESULTS.md ("The hard
protocol's objects") gives the share of the 100 views of the hemisphere that tell each pair apart
(``experiments/lookalike_visibility.py``).

Determinism: instance i of class c in split s (0 train, 1 test) draws its parameters from a NumPy generator
seeded by (seed, "lookalike", c, s, i) only, so train and test instances differ and an instance does not change
when the number of instances per class does. Each draw takes every part of the family in a fixed order
(cup: body, handle, lid, insert; bowl: body, spout, tube, lug) whether the class uses it or not, so the
instances of two lookalikes drawn from the same generator share the body and the common parts exactly
(``family_parts``). Parts are closed meshes with outward winding that overlap where they join (as builtin's
mug: an attachment's end sinks into the wall, never through it); surface samples are taken only outside the
other parts (``_surface_samples``), so the lid, a plug, leaves no samples inside the cup. Units: metres; the
model frame is the package's (z up, min z = 0, xy bounding box centred).
"""

from __future__ import annotations

import functools
import zlib
from collections.abc import Mapping

import numpy as np
import trimesh

from jaxcls.world.objects.builtin import (
    _BOWL,
    _MUG_HANDLE,
    _SECTIONS,
    Ranges,
    _bowl_body,
    _bowl_walls,
    _draw,
    _handle,
    _procedural_model,
    _revolve,
    _tube,
)
from jaxcls.world.objects.mesh import _rest_offset
from jaxcls.world.objects.model import ObjectModel, ObjectSet, kept_on_disk

# class -> (body, the parts it adds, in draw order)
CLASS_PARTS: Mapping[str, tuple[str, tuple[str, ...]]] = {
    "bowl": ("bowl", ()),
    "canister": ("cup", ("lid",)),
    "cup": ("cup", ()),
    "infuser_cup": ("cup", ("insert",)),
    "lug_bowl": ("bowl", ("lug",)),
    "mug": ("cup", ("handle",)),
    "spout_bowl": ("bowl", ("spout",)),
    "stein": ("cup", ("handle", "lid")),
    "tube_pan": ("bowl", ("tube",)),
}
LOOKALIKE_CLASSES = tuple(sorted(CLASS_PARTS))

# Parameter ranges (metres; fractions of the body where named so), drawn uniformly in key order.
_CUP: Ranges = {
    "radius": (0.03, 0.045), "height": (0.07, 0.12), "bevel": (0.002, 0.004), "wall": (0.003, 0.005),
    "bottom": (0.005, 0.01),
}
_LID: Ranges = {"recess": (0.002, 0.005)}
_INSERT: Ranges = {"radius_frac": (0.35, 0.55), "height_frac": (0.3, 0.5)}  # of the inner radius, depth
# builtin's bowl, 16 cm wide at most (room for a spout), its wall 5-8 mm (the spout's end sinks into it)
_LOOKALIKE_BOWL: Ranges = {**_BOWL, "radius": (0.05, 0.08), "wall": (0.005, 0.008)}
_BOWL_SPOUT: Ranges = {"tube": (0.004, 0.006), "reach": (0.012, 0.02), "rise": (0.003, 0.01)}
_TUBE: Ranges = {"radius_frac": (0.15, 0.25), "height_frac": (0.45, 0.75)}
# The lug: width (y) in metres, from bottom_frac to top_frac of the wall's height above the foot, its outer
# face at end_frac of the rim's radius.
_LUG: Ranges = {"width": (0.015, 0.025), "bottom_frac": (0.1, 0.2), "top_frac": (0.35, 0.5),
                "end_frac": (0.94, 0.98)}

_SPLIT = {"train": 0, "test": 1}


def lookalike_pairs() -> tuple[tuple[str, str, str], ...]:
    """(class, lookalike, part) for every two classes of one body whose parts differ by exactly ``part``
    (the lookalike has it), sorted."""
    out = []
    for a, (body_a, parts_a) in CLASS_PARTS.items():
        for b, (body_b, parts_b) in CLASS_PARTS.items():
            extra = set(parts_b) - set(parts_a)
            if body_a == body_b and set(parts_a) <= set(parts_b) and len(extra) == 1:
                out.append((a, b, extra.pop()))
    return tuple(sorted(out))


def _sunk_end(p: Mapping[str, float], z: float, half_height: float, half_width: float) -> float:
    """Where a horizontal attachment at height ``z`` on the +x side of the bowl of parameters ``p`` ends inside
    the wall (metres from the axis), its end cap (a vertical face within z +- ``half_height``, y +-
    ``half_width``) inside the wall: midway between the inner wall's widest and the outer wall's narrowest radius
    over that height (the polylines the body is revolved from; the outer one shrunk to its polygon's flats and
    to the cap's half-width)."""
    outer, inner = (np.asarray(line) for line in _bowl_walls(p))
    span = np.linspace(z - half_height, z + half_height, 9)
    x_out = np.interp(span, outer[:, 1], outer[:, 0]).min() * np.cos(np.pi / _SECTIONS)
    x_lo, x_hi = np.interp(span, inner[:, 1], inner[:, 0]).max(), np.sqrt(x_out**2 - half_width**2)
    if x_hi - x_lo < 0.001:
        raise AssertionError(f"bowl: the wall is {x_hi - x_lo:.4f} m thick where a part joins it at z = {z:.4f}")
    return float((x_lo + x_hi) / 2)


def _spout(x_in: float, z0: float, x_end: float, z_end: float, tube: float) -> trimesh.Trimesh:
    """A solid spout of radius ``tube`` on the +x side: leaves the wall horizontally at ``x_in`` from the axis
    (its end cap, a vertical disc, inside the wall) and height ``z0``, bends up along a quadratic Bezier curve
    and ends ``x_end`` out from the axis at height ``z_end`` (metres)."""
    s = np.linspace(0.0, 1.0, 9)[:, None]
    p0, p1, p2 = np.array([x_in, 0, z0]), np.array([x_in + 0.6 * (x_end - x_in), 0, z0]), np.array([x_end, 0, z_end])
    points = (1 - s) ** 2 * p0 + 2 * (1 - s) * s * p1 + s**2 * p2
    tangents = 2 * (1 - s) * (p1 - p0) + 2 * s * (p2 - p1)
    return _tube(points, tangents, tube)


def _cup_parts(rng: np.random.Generator) -> dict[str, trimesh.Trimesh]:
    """Every part of the cup family drawn from ``rng``: body, handle (+x), lid, insert."""
    p = _draw(rng, _CUP)
    q_handle, q_lid, q_insert = _draw(rng, _MUG_HANDLE), _draw(rng, _LID), _draw(rng, _INSERT)
    r, h, w, b, z_in = p["radius"], p["height"], p["wall"], p["bevel"], p["bottom"]
    body = _revolve([(0, 0), (r - b, 0), (r, b), (r, h), (r - w, h), (r - w, z_in), (0, z_in)])
    # The handle's ends sink half the wall (their end caps stay inside it, never in the cavity).
    z_mid, half = q_handle["centre_frac"] * h, q_handle["span_frac"] * h / 2
    handle = _handle(r, z_mid - half, z_mid + half, q_handle["tube"], q_handle["reach"], q_handle["corner_frac"],
                     sink=w / 2 / q_handle["tube"])
    # The lid: a plug from inside the bottom up to the lid's face, its side inside the wall.
    lid = trimesh.creation.cylinder(radius=r - w / 2, segment=[[0, 0, z_in / 2], [0, 0, h - q_lid["recess"]]],
                                    sections=_SECTIONS)
    insert_top = z_in + q_insert["height_frac"] * (h - z_in)
    insert = trimesh.creation.cylinder(radius=q_insert["radius_frac"] * (r - w),
                                       segment=[[0, 0, z_in / 2], [0, 0, insert_top]], sections=_SECTIONS)
    return {"body": body, "handle": handle, "lid": lid, "insert": insert}


def _bowl_parts(rng: np.random.Generator) -> dict[str, trimesh.Trimesh]:
    """Every part of the bowl family drawn from ``rng``: body, spout (+x) just below the rim, central tube,
    lug (+x) on the lower wall."""
    p = _draw(rng, _LOOKALIKE_BOWL)
    q_spout, q_tube, q_lug = _draw(rng, _BOWL_SPOUT), _draw(rng, _TUBE), _draw(rng, _LUG)
    r, h, z_in = p["radius"], p["height"], p["foot_height"] + p["bottom"]
    z_spout = h - q_spout["tube"] - 0.001
    spout = _spout(_sunk_end(p, z_spout, q_spout["tube"], q_spout["tube"]), z_spout, r + q_spout["reach"],
                   z_spout + q_spout["rise"], q_spout["tube"])
    tube = trimesh.creation.cylinder(
        radius=q_tube["radius_frac"] * (r - p["wall"]),
        segment=[[0, 0, z_in - p["bottom"] / 2], [0, 0, z_in + q_tube["height_frac"] * (h - z_in)]],
        sections=_SECTIONS)
    return {"body": _bowl_body(p), "spout": spout, "tube": tube, "lug": _lug(p, q_lug)}


def _lug(p: Mapping[str, float], q: Mapping[str, float]) -> trimesh.Trimesh:
    """A block on the +x side of the lower wall of the bowl of parameters ``p``, under the rim's overhang (the
    ``_LUG`` parameters ``q``): the convex hull of its outer face, vertical at ``end_frac`` of the rim's radius,
    and of points on the wall's mid-surface over the same heights (9 heights at most 4 mm apart: the chords
    between them stay inside the 5-8 mm wall, never in the cavity)."""
    h, hf, half = p["height"], p["foot_height"], q["width"] / 2
    z = np.linspace(hf + q["bottom_frac"] * (h - hf), hf + q["top_frac"] * (h - hf), 9)
    outer, inner = (np.asarray(line) for line in _bowl_walls(p))
    mid = (np.interp(z, outer[:, 1], outer[:, 0]) + np.interp(z, inner[:, 1], inner[:, 0])) / 2
    x_wall = np.sqrt(mid**2 - half**2)
    x_end = q["end_frac"] * p["radius"]
    points = [(x, y, zi) for x, zi in zip(x_wall, z, strict=True) for y in (-half, half)]
    points += [(x_end, y, zi) for zi in z[[0, -1]] for y in (-half, half)]
    return trimesh.convex.convex_hull(np.asarray(points))


def family_parts(class_name: str, rng: np.random.Generator) -> dict[str, trimesh.Trimesh]:
    """Every part of ``class_name``'s family drawn from ``rng`` (the class's own and its lookalikes'), keyed
    ``body`` and by part name, in the body's frame (before the rest offset of ``_assemble``), metres."""
    body, _ = CLASS_PARTS[class_name]
    return _cup_parts(rng) if body == "cup" else _bowl_parts(rng)


def _instance_parts(class_name: str, rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """The closed parts of one instance, body first, then the class's parts in ``CLASS_PARTS`` order."""
    parts = family_parts(class_name, rng)
    return [parts["body"], *(parts[name] for name in CLASS_PARTS[class_name][1])]


def instance_sequence(seed: int, class_name: str, split: str, index: int) -> np.random.SeedSequence:
    """The seed sequence of one instance (``split``: train or test); its first spawned child draws the shape,
    the second the surface samples."""
    return np.random.SeedSequence([seed, zlib.crc32(b"lookalike"), zlib.crc32(class_name.encode()), _SPLIT[split],
                                   index])


def model_parts(class_name: str, split: str, index: int, seed: int = 0) -> dict[str, trimesh.Trimesh]:
    """The parts of instance ``index`` of ``class_name`` in ``split`` (``train`` or ``test``) of the set of
    ``seed``, keyed ``body`` and by ``CLASS_PARTS`` name, in the model frame (metres): concatenated in this
    order, their vertices and faces are the set's model's mesh."""
    shape_seq, _ = instance_sequence(seed, class_name, split, index).spawn(2)
    every = family_parts(class_name, np.random.default_rng(shape_seq))
    parts = {name: every[name] for name in ("body", *CLASS_PARTS[class_name][1])}
    offset = _rest_offset(np.concatenate([np.asarray(p.vertices) for p in parts.values()]))
    return {name: part.copy().apply_translation(offset) for name, part in parts.items()}


def _lookalike_model(class_name: str, split: str, index: int, seed: int, surface_samples: int,
                     name: str) -> ObjectModel:
    """One instance, named ``name``: its shape and its surface samples from their own generators (so the
    samples' count does not change the shape); its largest extent checked against builtin's 5-20 cm."""
    return _procedural_model(class_name, _instance_parts, instance_sequence(seed, class_name, split, index),
                             surface_samples, name)


@functools.lru_cache(maxsize=8)
def _lookalike_cached(seed: int, train_per_class: int, test_per_class: int, surface_samples: int) -> ObjectSet:
    def build() -> ObjectSet:
        train, test = [], []
        for class_name in LOOKALIKE_CLASSES:
            for i in range(train_per_class):
                train.append(_lookalike_model(class_name, "train", i, seed, surface_samples, f"{class_name}_{i:03d}"))
            for i in range(test_per_class):
                test.append(_lookalike_model(class_name, "test", i, seed, surface_samples,
                                             f"{class_name}_test_{i:03d}"))
        return ObjectSet(f"lookalike_seed{seed}", LOOKALIKE_CLASSES, tuple(train), tuple(test))

    return kept_on_disk("lookalike", (seed, train_per_class, test_per_class, surface_samples), build)


def lookalike_object_set(seed: int = 0, train_per_class: int = 8, test_per_class: int = 4,
                         surface_samples: int = 2048) -> ObjectSet:
    """The lookalike set (see the module docstring), cached: the same arguments return the same object.

    Train instances are named ``mug_000``..., held-out test instances ``mug_test_000``..., as builtin's.
    """
    if seed < 0 or train_per_class < 0 or test_per_class < 0:
        raise ValueError("seed, train_per_class and test_per_class must be non-negative")
    return _lookalike_cached(int(seed), int(train_per_class), int(test_per_class), int(surface_samples))
