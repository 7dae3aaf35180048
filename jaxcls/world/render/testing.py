"""Small scenes that follow the scene contract, for the render tests and benchmarks only.

The real scenes come from ``jaxcls.world.scenes``; these stand in for them where a known layout is needed:
analytic primitives to check depth against, and a few trimesh meshes of realistic triangle counts.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
import trimesh

from jaxcls import geometry
from jaxcls.geometry import Intrinsics
from jaxcls.world.render import contract

TABLE_HALF_EXTENT = (0.5, 0.4)  # m, x and y
TABLE_THICKNESS = 0.04  # m


def scene_spec(intrinsics: Intrinsics, table_height: float = 0.0) -> mujoco.MjSpec:
    """An MjSpec holding the table (top face at ``table_height``) and the mocap depth camera, no objects."""
    spec = mujoco.MjSpec()
    spec.compiler.degree = False
    spec.add_material(name="table_mat", rgba=[0.6, 0.5, 0.4, 1.0])
    spec.add_material(name="object_mat", rgba=[0.3, 0.5, 0.8, 1.0])
    spec.worldbody.add_geom(
        name=contract.TABLE_GEOM, type=mujoco.mjtGeom.mjGEOM_BOX, material="table_mat",
        size=[*TABLE_HALF_EXTENT, TABLE_THICKNESS / 2], pos=[0.0, 0.0, table_height - TABLE_THICKNESS / 2])
    camera = spec.worldbody.add_body(name=contract.CAMERA_BODY, mocap=True,
                                     pos=[0.0, 0.0, table_height + 1.0])
    camera.add_camera(name=contract.CAMERA_NAME, fovy=intrinsics.fovy_deg,
                      resolution=[intrinsics.width, intrinsics.height])
    return spec


def add_object(spec: mujoco.MjSpec, index: int, pos: Sequence[float], yaw: float = 0.0,
               **geom: object) -> None:
    """Body ``object_<index>`` at ``pos`` (m) turned by ``yaw`` (rad) about z, with one geom (``add_geom``
    keyword arguments; the material defaults to the object material)."""
    body = spec.worldbody.add_body(name=f"object_{index}", pos=list(pos),
                                   quat=geometry.rotation_to_quat(geometry.yaw_matrix_np(yaw)).tolist())
    geom.setdefault("material", "object_mat")
    body.add_geom(**geom)


def add_mesh_object(spec: mujoco.MjSpec, index: int, mesh: trimesh.Trimesh, xy: Sequence[float],
                    yaw: float = 0.0, table_height: float = 0.0) -> None:
    """Body ``object_<index>`` standing on the table at ``xy`` with the z-up ``mesh`` as its geom."""
    name = f"mesh_{index}"
    spec.add_mesh(name=name, uservert=np.asarray(mesh.vertices, float).ravel().tolist(),
                  userface=np.asarray(mesh.faces, int).ravel().tolist())
    z = table_height - float(mesh.bounds[0, 2])
    add_object(spec, index, [xy[0], xy[1], z], yaw, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name)


def primitives_scene(intrinsics: Intrinsics, table_height: float = 0.0, mesh: bool = True) -> mujoco.MjModel:
    """Table, a yawed box ``object_0``, a sphere ``object_1`` and (``mesh``) a cylinder mesh ``object_2``.

    box: half sizes (0.05, 0.04, 0.06) at (0.12, 0.02) yawed 0.5 rad; sphere: radius 0.05 at (-0.1, 0.1);
    both standing on the table. A geom of a body that is no object (a marker) checks that rays ignore it.
    """
    spec = scene_spec(intrinsics, table_height)
    h = table_height
    add_object(spec, 0, [0.12, 0.02, h + 0.06], 0.5, type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 0.04, 0.06])
    add_object(spec, 1, [-0.1, 0.1, h + 0.05], type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.05, 0.0, 0.0])
    if mesh:
        cylinder = trimesh.creation.cylinder(radius=0.04, height=0.1, sections=24)
        add_mesh_object(spec, 2, cylinder, [-0.05, -0.12], 0.3, h)
    marker = spec.worldbody.add_body(name="marker", pos=[0.3, -0.25, h + 0.5])
    marker.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.03, 0.0, 0.0], material="object_mat")
    return spec.compile()


def mesh_scene(intrinsics: Intrinsics, num_objects: int = 5, seed: int = 0,
               table_height: float = 0.0) -> mujoco.MjModel:
    """``num_objects`` trimesh objects (about 6k triangles for five) on a ring, random yaws: a stand-in for
    a ``jaxcls.world.scenes`` scene."""
    shapes = [
        trimesh.creation.cylinder(radius=0.04, height=0.14, sections=64),
        trimesh.creation.icosphere(subdivisions=3, radius=0.05),
        trimesh.creation.torus(major_radius=0.05, minor_radius=0.02, major_sections=64, minor_sections=32),
        trimesh.creation.cone(radius=0.05, height=0.12, sections=64),
        trimesh.creation.box(extents=[0.08, 0.06, 0.1]),
        trimesh.creation.capsule(height=0.1, radius=0.03, count=[32, 32]),
    ]
    rng = np.random.default_rng(seed)
    spec = scene_spec(intrinsics, table_height)
    for i in range(num_objects):
        angle = 2 * np.pi * i / num_objects
        xy = 0.17 * np.array([np.cos(angle), np.sin(angle)])
        add_mesh_object(spec, i, shapes[i % len(shapes)], xy, float(rng.uniform(0, 2 * np.pi)), table_height)
    return spec.compile()
