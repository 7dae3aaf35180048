"""Object sets: the builtin procedural classes and the folder / BOP loaders."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest
import trimesh

from jaxcls import config
from jaxcls.world import objects as assets

CLASSES = ("bottle", "bowl", "box", "can", "drill", "jug", "lamp", "mug")
# Samples are stored in f32: a few 1e-8 m of rounding on coordinates up to 0.2 m.
ON_SURFACE_TOL = 1e-6


@pytest.fixture(scope="module")
def builtin() -> assets.ObjectSet:
    return assets.builtin_object_set()


def _per_class(models, class_name):
    return [m for m in models if m.class_name == class_name]


def _nearest_faces(mesh: trimesh.Trimesh, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Brute-force distance [P] from each point to the mesh and the index [P] of the nearest face."""
    triangles = np.asarray(mesh.triangles)
    n_p, n_f = len(points), len(triangles)
    closest = trimesh.triangles.closest_point(np.tile(triangles, (n_p, 1, 1)), np.repeat(points, n_f, axis=0))
    dist = np.linalg.norm(closest - np.repeat(points, n_f, axis=0), axis=1).reshape(n_p, n_f)
    return dist.min(axis=1), dist.argmin(axis=1)


# ----------------------------------------------------------------------------------------------------------
# Builtin set


def test_builtin_classes_and_splits(builtin):
    assert builtin.classes == CLASSES
    assert [builtin.class_index(c) for c in CLASSES] == list(range(8))
    for class_name in CLASSES:
        train, test = _per_class(builtin.train, class_name), _per_class(builtin.test, class_name)
        assert len(train) == 8 and len(test) == 4
    names = [m.name for m in builtin.split("all")]
    assert len(names) == len(set(names)) == 96
    assert builtin.split("all") == builtin.train + builtin.test
    assert builtin.split("train") is builtin.train and builtin.split("test") is builtin.test
    with pytest.raises(ValueError, match="split"):
        builtin.split("val")
    with pytest.raises(KeyError, match="teapot"):
        builtin.class_index("teapot")


def test_builtin_sizes_rest_pose_and_budget(builtin):
    for model in builtin.split("all"):
        vertices = np.asarray(model.mesh.vertices)
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        assert 0.05 <= (hi - lo).max() <= 0.20, model.name
        assert lo[2] == pytest.approx(0.0, abs=1e-12), model.name
        np.testing.assert_allclose((lo[:2] + hi[:2]) / 2, 0.0, atol=1e-12, err_msg=model.name)
        assert len(model.mesh.faces) <= 2500, model.name


def test_builtin_meshes_are_closed_outward_and_clean(builtin):
    for model in builtin.split("all"):
        mesh = model.mesh
        assert mesh.is_watertight and mesh.is_winding_consistent, model.name
        parts = mesh.split(only_watertight=False)
        assert len(parts) == {"mug": 2, "jug": 2, "drill": 5}.get(model.class_name, 1), model.name
        assert all(part.volume > 0 for part in parts), model.name
        assert mesh.area_faces.min() > 1e-8, model.name
        assert len(np.unique(np.sort(mesh.faces, axis=1), axis=0)) == len(mesh.faces), model.name
        assert np.isfinite(mesh.vertices).all()


def test_builtin_meshes_load_in_mujoco(builtin):
    spec = mujoco.MjSpec()
    for i, model in enumerate(builtin.split("all")):
        mesh = spec.add_mesh()
        mesh.name = model.name
        mesh.uservert = np.asarray(model.mesh.vertices, np.float32).ravel().tolist()
        mesh.userface = np.asarray(model.mesh.faces, np.int32).ravel().tolist()
        body = spec.worldbody.add_body(name=model.name, pos=[0.3 * i, 0.0, 0.0])
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=model.name)
    compiled = spec.compile()
    assert compiled.nmesh == 96
    np.testing.assert_array_equal(compiled.mesh_facenum, [len(m.mesh.faces) for m in builtin.split("all")])


def test_builtin_is_cached_and_deterministic(builtin):
    assert assets.builtin_object_set(0) is builtin
    assert assets.builtin_object_set(seed=0, train_per_class=8) is builtin
    small = assets.builtin_object_set(seed=0, train_per_class=2, test_per_class=1, surface_samples=2048)
    for class_name in CLASSES:
        regenerated, cached = _per_class(small.train, class_name), _per_class(builtin.train, class_name)
        for a, b in zip(regenerated, cached[:2], strict=True):
            assert a.name == b.name
            np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
            np.testing.assert_array_equal(a.surface_points, b.surface_points)
    other = assets.builtin_object_set(seed=1, train_per_class=2, test_per_class=1, surface_samples=64)
    for a, b in zip(other.train, small.train, strict=True):
        assert a.name == b.name
        assert a.mesh.vertices.shape != b.mesh.vertices.shape or not np.allclose(a.mesh.vertices,
                                                                                 b.mesh.vertices)


def test_builtin_train_and_test_instances_differ(builtin):
    for class_name in CLASSES:
        extents = [tuple(np.round(np.ptp(m.mesh.vertices, axis=0), 9))
                   for m in _per_class(builtin.split("all"), class_name)]
        assert len(set(extents)) == len(extents), class_name


def test_surface_samples_lie_on_the_mesh_with_face_normals(builtin):
    for class_name in CLASSES:
        for model in (_per_class(builtin.train, class_name)[0], _per_class(builtin.test, class_name)[0]):
            assert model.surface_points.shape == model.surface_normals.shape == (2048, 3)
            assert model.surface_points.dtype == model.surface_normals.dtype == np.float32
            np.testing.assert_allclose(np.linalg.norm(model.surface_normals, axis=1), 1.0, atol=1e-5)
            points = model.surface_points[:128].astype(np.float64)
            dist, face = _nearest_faces(model.mesh, points)
            assert dist.max() < ON_SURFACE_TOL, model.name
            agree = np.einsum("ij,ij->i", model.mesh.face_normals[face], model.surface_normals[:128])
            assert np.mean(agree > 0.999) > 0.97, model.name


def test_winding_numbers_match_analytic_containment():
    """The helper the sampler and the next tests rely on, against exact inside/outside of two solids."""
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.0, 1.0, size=(400, 3))
    box = trimesh.creation.box(extents=[1.0, 1.2, 0.8])
    inside_box = np.all(np.abs(points) < [0.5, 0.6, 0.4], axis=1)
    got = assets._winding_numbers(points, np.asarray(box.triangles))
    np.testing.assert_allclose(got, inside_box, atol=1e-9)
    tube = trimesh.creation.cylinder(radius=0.5, height=1.0, sections=64)
    radius = np.hypot(points[:, 0], points[:, 1])
    inscribed = 0.5 * np.cos(np.pi / 64)
    clear = (np.abs(radius - 0.5) > 0.5 - inscribed + 1e-6) & (np.abs(np.abs(points[:, 2]) - 0.5) > 1e-6)
    expected = (radius < 0.5) & (np.abs(points[:, 2]) < 0.5)
    got = assets._winding_numbers(points[clear], np.asarray(tube.triangles))
    np.testing.assert_allclose(got, expected[clear], atol=1e-9)


def _off_surface_failures(model: assets.ObjectModel, stride: int, eps: float = 2e-5) -> int:
    """Samples whose point one step along the normal is inside, or one step against it is outside."""
    points = model.surface_points[::stride].astype(np.float64)
    normals = model.surface_normals[::stride].astype(np.float64)
    triangles = np.asarray(model.mesh.triangles)
    outside = assets._winding_numbers(points + eps * normals, triangles)
    inside = assets._winding_numbers(points - eps * normals, triangles)
    return int(np.sum((outside > 0.5) | (inside < 0.5)))


def test_surface_normals_point_out_of_the_union(builtin):
    """Inside one step against the normal, outside one step along it (allowing a sample within the step of
    an acute edge, such as a bowl's rim)."""
    for model in builtin.split("all"):
        assert _off_surface_failures(model, stride=16) <= 1, model.name


def test_no_samples_on_parts_buried_in_other_parts(builtin):
    """Handle ends and drill joints sink into the body; samples there would be inside the union (sampling
    without the filter puts 2-15 % of the samples there)."""
    for class_name in ("mug", "jug", "drill"):
        for model in (_per_class(builtin.train, class_name)[0], _per_class(builtin.test, class_name)[0]):
            assert _off_surface_failures(model, stride=1) <= 4, model.name


def test_surface_samples_are_area_uniform(builtin):
    model = _per_class(builtin.train, "box")[0]
    lo, hi = model.bounds
    size = hi - lo
    points = model.surface_points
    total = 2 * (size[0] * size[1] + size[1] * size[2] + size[0] * size[2])
    for axis in range(3):
        on_face = np.isclose(points[:, axis], lo[axis], atol=1e-6) | np.isclose(points[:, axis], hi[axis],
                                                                                 atol=1e-6)
        expected = 2 * np.prod(np.delete(size, axis)) / total
        assert abs(on_face.mean() - expected) < 0.04


def test_mug_is_a_can_plus_a_handle():
    """Same per-instance stream: the mug's body is exactly the can's; the handle is the only extra part."""
    for pair in (("mug", "can"), ("jug", "bottle")):
        for seed in range(5):
            with_handle = assets._instance_parts(pair[0], np.random.default_rng(seed))
            body_only = assets._instance_parts(pair[1], np.random.default_rng(seed))
            assert len(with_handle) == 2 and len(body_only) == 1
            np.testing.assert_array_equal(with_handle[0].vertices, body_only[0].vertices)
            np.testing.assert_array_equal(with_handle[0].faces, body_only[0].faces)


def test_mug_and_can_bodies_share_ranges_and_the_handle_widens_one_direction(builtin):
    radius, height = assets._CAN_BODY["radius"], assets._CAN_BODY["height"]
    min_reach = assets._MUG_HANDLE["reach"][0]
    for class_name in ("mug", "can"):
        for model in _per_class(builtin.split("all"), class_name):
            size = np.ptp(model.mesh.vertices, axis=0)
            assert 2 * radius[0] - 1e-9 <= size[1] <= 2 * radius[1] + 1e-9, model.name
            assert height[0] - 1e-9 <= size[2] <= height[1] + 1e-9, model.name
            foot = model.footprint()
            width_x, width_y = np.ptp(foot, axis=0)
            if class_name == "mug":
                assert width_x > width_y + min_reach, model.name
            else:
                assert width_x == pytest.approx(width_y, abs=1e-9), model.name


def test_bounds_corners_and_footprint_contain_the_mesh(builtin):
    for model in builtin.split("all"):
        vertices = np.asarray(model.mesh.vertices)
        lo, hi = model.bounds
        assert np.all(vertices >= lo) and np.all(vertices <= hi)
        corners = model.cuboid_corners
        assert corners.shape == (8, 3)
        assert {tuple(c) for c in corners} == {(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                                                for z in (lo[2], hi[2])}
        np.testing.assert_array_equal(corners[0], lo)
        np.testing.assert_array_equal(corners[7], hi)
        np.testing.assert_array_equal(corners[1], [lo[0], lo[1], hi[2]])
        foot = model.footprint()
        edges = np.roll(foot, -1, axis=0) - foot
        rel = vertices[None, :, :2] - foot[:, None, :]
        cross = edges[:, None, 0] * rel[..., 1] - edges[:, None, 1] * rel[..., 0]
        assert cross.min() > -1e-12, model.name
        area = 0.5 * np.sum(foot[:, 0] * np.roll(foot[:, 1], -1) - np.roll(foot[:, 0], -1) * foot[:, 1])
        assert area > 0, model.name


# ----------------------------------------------------------------------------------------------------------
# normalise_mesh


@pytest.mark.parametrize("up_axis", ["x", "y", "z", "-x", "-y", "-z"])
def test_up_rotation_is_proper_and_turns_the_axis_up(up_axis):
    rotation = assets._up_rotation(up_axis)
    up = np.zeros(3)
    up["xyz".index(up_axis[-1])] = -1.0 if up_axis.startswith("-") else 1.0
    np.testing.assert_allclose(rotation @ up, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)


@pytest.mark.parametrize("up_axis", ["x", "y", "z", "-x", "-y", "-z"])
def test_normalise_mesh_turns_up_axis_to_z(up_axis):
    box = trimesh.creation.box(extents=[1.0, 2.0, 3.0])
    box.apply_translation([5.0, -7.0, 11.0])
    out = assets.normalise_mesh(box, scale=0.01, up_axis=up_axis)
    assert out is not box and out.is_watertight and out.is_winding_consistent
    axis = "xyz".index(up_axis[-1])
    assert np.ptp(out.vertices[:, 2]) == pytest.approx(0.01 * [1.0, 2.0, 3.0][axis])
    assert out.volume == pytest.approx(6e-6)
    assert out.bounds[0, 2] == pytest.approx(0.0)
    np.testing.assert_allclose(out.bounds[:, :2].sum(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(box.bounds, [[4.5, -8.0, 9.5], [5.5, -6.0, 12.5]])


def test_normalise_mesh_repairs_orientation_and_drops_degenerate_faces():
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    inside_out = trimesh.Trimesh(vertices=box.vertices, faces=box.faces[:, ::-1], process=False)
    assert inside_out.volume < 0
    assert assets.normalise_mesh(inside_out).volume == pytest.approx(1.0)
    faces = np.concatenate([box.faces, [[0, 1, 1], [0, 0, 0]]])
    out = assets.normalise_mesh(trimesh.Trimesh(vertices=box.vertices, faces=faces, process=False))
    assert len(out.faces) == 12


def test_normalise_mesh_rejects_bad_meshes():
    box = trimesh.creation.box()
    with pytest.raises(ValueError, match="up_axis"):
        assets.normalise_mesh(box, up_axis="w")
    with pytest.raises(ValueError, match="no faces"):
        assets.normalise_mesh(trimesh.Trimesh())
    vertices = np.array(box.vertices)
    vertices[3, 1] = np.inf
    bad = trimesh.Trimesh(vertices=vertices, faces=box.faces, process=False)
    with pytest.raises(ValueError, match="non-finite"):
        assets.normalise_mesh(bad)


# ----------------------------------------------------------------------------------------------------------
# load_folder


def _write_class_folder(root: Path) -> None:
    """Millimetre meshes, off-centre and above the table, in three formats."""
    (root / "block").mkdir(parents=True)
    (root / "tin").mkdir()
    a = trimesh.creation.box(extents=[40.0, 20.0, 60.0])
    a.apply_translation([100.0, 50.0, 30.0])
    a.export(root / "block" / "a.obj")
    b = trimesh.creation.box(extents=[30.0, 30.0, 30.0])
    b.export(root / "block" / "b.ply")
    (root / "block" / "notes.txt").write_text("not a mesh, and not one by its name either")
    trimesh.creation.cylinder(radius=25.0, height=90.0, sections=32).export(root / "tin" / "c.stl")


def test_load_folder_converts_units_and_rests_models(tmp_path):
    _write_class_folder(tmp_path / "objs")
    objects = assets.load_folder(tmp_path / "objs", scale=0.001, surface_samples=256)
    assert objects.name == "objs"
    assert objects.classes == ("block", "tin")
    assert [m.name for m in objects.train] == ["block_a", "block_b", "tin_c"]
    assert objects.test == ()
    a = objects.train[0]
    np.testing.assert_allclose(np.ptp(a.mesh.vertices, axis=0), [0.04, 0.02, 0.06], atol=1e-9)
    np.testing.assert_allclose(a.bounds, [[-0.02, -0.01, 0.0], [0.02, 0.01, 0.06]], atol=1e-9)
    np.testing.assert_allclose(np.ptp(objects.train[2].mesh.vertices, axis=0), [0.05, 0.05, 0.09], atol=1e-9)
    for model in objects.train:
        assert model.surface_points.shape == (256, 3)
        dist, _ = _nearest_faces(model.mesh, model.surface_points[:64].astype(np.float64))
        assert dist.max() < ON_SURFACE_TOL
    again = assets.load_folder(tmp_path / "objs", scale=0.001, surface_samples=256)
    np.testing.assert_array_equal(again.train[1].surface_points, objects.train[1].surface_points)


def test_load_folder_holds_out_the_last_instances(tmp_path):
    _write_class_folder(tmp_path)
    objects = assets.load_folder(tmp_path, test_fraction=0.5, surface_samples=32, scale=0.001)
    assert [m.name for m in objects.train] == ["block_a", "tin_c"]
    assert [m.name for m in objects.test] == ["block_b"]
    with pytest.raises(ValueError, match="test_fraction"):
        assets.load_folder(tmp_path, test_fraction=1.0, scale=0.001)


def test_load_folder_errors_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere"):
        assets.load_folder(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="empty"):
        assets.load_folder(tmp_path / "empty")
    (tmp_path / "noclass" / "mug").mkdir(parents=True)
    with pytest.raises(ValueError, match=re.escape(str(tmp_path / "noclass" / "mug"))):
        assets.load_folder(tmp_path / "noclass")

    cases = {
        "hollow.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\n",
        "text.ply": "this is a text file, not a PLY\n",
        "nan.obj": "v nan 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    }
    messages = {"hollow.obj": "no faces", "text.ply": "cannot read", "nan.obj": "non-finite"}
    for file_name, text in cases.items():
        root = tmp_path / file_name.replace(".", "_")
        (root / "thing").mkdir(parents=True)
        (root / "thing" / file_name).write_text(text)
        with pytest.raises(ValueError, match=re.escape(file_name)) as error:
            assets.load_folder(root)
        assert messages[file_name] in str(error.value)


def test_load_folder_rejects_millimetre_models_without_scale(tmp_path):
    """Millimetre meshes loaded as metres (a 60 mm block is 60 m) fail at load time, naming the file and the
    fix, instead of later in scene building."""
    _write_class_folder(tmp_path / "objs")
    a = tmp_path / "objs" / "block" / "a.obj"
    with pytest.raises(ValueError, match=re.escape(str(a))) as error:
        assets.load_folder(tmp_path / "objs", surface_samples=16)
    message = str(error.value)
    assert "largest extent 60 m" in message and "millimetres" in message
    assert "objects.scale=0.001" in message and "pass scale=0.001" in message  # YAML / CLI and Python
    config_folder = assets.ObjectSetConfig(source=str(tmp_path / "objs"), surface_samples=16)
    with pytest.raises(ValueError, match=r"a\.obj: largest extent 60 m.*objects\.scale=0\.001"):
        assets.object_set_from_config(config_folder)
    assert assets.MAX_MODEL_EXTENT == 5.0


def test_load_folder_rejects_tiny_models(tmp_path):
    """Metre meshes loaded with scale=0.001 come out under a millimetre: the error names the file and scale."""
    (tmp_path / "objs" / "cube").mkdir(parents=True)
    trimesh.creation.box(extents=[0.05, 0.05, 0.05]).export(tmp_path / "objs" / "cube" / "small.stl")
    assert assets.load_folder(tmp_path / "objs", surface_samples=16).classes == ("cube",)
    with pytest.raises(ValueError, match=re.escape(str(tmp_path / "objs" / "cube" / "small.stl"))) as error:
        assets.load_folder(tmp_path / "objs", surface_samples=16, scale=0.001)
    message = str(error.value)
    assert "largest extent 5e-05 m" in message and "under 1 mm" in message
    assert "in metres" in message and "objects.scale" in message and "scale argument" in message


# ----------------------------------------------------------------------------------------------------------
# load_bop


def _write_bop(root: Path, info_overrides: dict | None = None, extra_ids: tuple[int, ...] = ()) -> dict:
    """A two-object BOP dataset in mm: a box and a cylinder centred on their origin, as BOP models are."""
    models = root / "models"
    models.mkdir(parents=True)
    meshes = {1: trimesh.creation.box(extents=[40.0, 60.0, 80.0]),
              2: trimesh.creation.cylinder(radius=30.0, height=100.0, sections=32)}
    info = {}
    for obj_id, mesh in meshes.items():
        mesh.export(models / f"obj_{obj_id:06d}.ply")
        lo, size = mesh.bounds[0], np.ptp(mesh.vertices, axis=0)
        diameter = max(np.linalg.norm(u - v) for u in mesh.vertices for v in mesh.vertices)
        info[str(obj_id)] = {"diameter": float(diameter), "min_x": lo[0], "min_y": lo[1], "min_z": lo[2],
                             "size_x": size[0], "size_y": size[1], "size_z": size[2]}
    for obj_id in extra_ids:
        info[str(obj_id)] = dict(info["1"])
    for key, fields in (info_overrides or {}).items():
        info[key].update(fields)
    (models / "models_info.json").write_text(json.dumps(info))
    return meshes


def test_load_bop_converts_mm_to_metres(tmp_path):
    meshes = _write_bop(tmp_path / "lm")
    (tmp_path / "lm" / "classes.json").write_text(json.dumps({"1": "box", "2": "can"}))
    objects = assets.load_bop(tmp_path / "lm", surface_samples=128)
    assert objects.name == "lm"
    assert objects.classes == ("box", "can")
    assert [(m.name, m.class_name) for m in objects.train] == [("obj_000001", "box"), ("obj_000002", "can")]
    for model, mesh in zip(objects.train, meshes.values(), strict=True):
        np.testing.assert_allclose(np.ptp(model.mesh.vertices, axis=0), 0.001 * np.ptp(mesh.vertices, axis=0),
                                   rtol=1e-12)
        assert model.mesh.volume == pytest.approx(1e-9 * mesh.volume)
        assert model.bounds[0, 2] == pytest.approx(0.0)
    np.testing.assert_allclose(objects.train[0].bounds, [[-0.02, -0.03, 0.0], [0.02, 0.03, 0.08]], atol=1e-12)
    assert assets.load_object_set(str(tmp_path / "lm"), surface_samples=128).classes == ("box", "can")


def test_load_bop_class_names_default_argument_and_up_axis(tmp_path):
    _write_bop(tmp_path)
    objects = assets.load_bop(tmp_path, surface_samples=16)
    assert objects.classes == ("obj_000001", "obj_000002")
    objects = assets.load_bop(tmp_path / "models", class_names={1: "crate", 2: "crate"}, test_fraction=0.5,
                              surface_samples=16, up_axis="y")
    assert objects.classes == ("crate",)
    assert [m.name for m in objects.train] == ["obj_000001"]
    assert [m.name for m in objects.test] == ["obj_000002"]
    np.testing.assert_allclose(np.ptp(objects.train[0].mesh.vertices, axis=0), [0.08, 0.04, 0.06], atol=1e-12)


def test_load_bop_rejects_inconsistent_models_info(tmp_path):
    _write_bop(tmp_path, info_overrides={"2": {"size_z": 105.0}})
    message = r"inconsistent models_info.*models_info\.json key '2' has size_z = 105 mm.*obj_000002\.ply"
    with pytest.raises(ValueError, match=message):
        assets.load_bop(tmp_path)


def test_load_bop_accepts_sizes_within_tolerance(tmp_path):
    _write_bop(tmp_path, info_overrides={"2": {"size_z": 100.9}, "1": {"min_x": -20.5}})
    assert len(assets.load_bop(tmp_path, surface_samples=16).train) == 2


def test_load_bop_errors_name_the_file_and_key(tmp_path):
    _write_bop(tmp_path / "missing", extra_ids=(3,))
    with pytest.raises(FileNotFoundError, match=r"key '3'.*obj_000003\.ply"):
        assets.load_bop(tmp_path / "missing")

    _write_bop(tmp_path / "orphan")
    trimesh.creation.box(extents=[10, 10, 10]).export(tmp_path / "orphan" / "models" / "obj_000007.ply")
    with pytest.raises(ValueError, match=r"obj_000007\.ply"):
        assets.load_bop(tmp_path / "orphan")

    _write_bop(tmp_path / "nofield")
    info_path = tmp_path / "nofield" / "models" / "models_info.json"
    info = json.loads(info_path.read_text())
    del info["1"]["size_y"]
    info_path.write_text(json.dumps(info))
    with pytest.raises(ValueError, match=r"key '1' lacks 'size_y'"):
        assets.load_bop(tmp_path / "nofield")

    _write_bop(tmp_path / "garbled")
    (tmp_path / "garbled" / "models" / "obj_000002.ply").write_text("ply?\nno\n")
    with pytest.raises(ValueError, match=r"obj_000002\.ply"):
        assets.load_bop(tmp_path / "garbled")

    (tmp_path / "noinfo" / "models").mkdir(parents=True)
    with pytest.raises(FileNotFoundError, match=r"models_info\.json"):
        assets.load_bop(tmp_path / "noinfo")

    _write_bop(tmp_path / "badjson")
    (tmp_path / "badjson" / "models" / "models_info.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"models_info\.json"):
        assets.load_bop(tmp_path / "badjson")

    _write_bop(tmp_path / "names")
    (tmp_path / "names" / "class_names.json").write_text(json.dumps({"1": "box", "9": "ghost"}))
    with pytest.raises(ValueError, match=r"\[9\]"):
        assets.load_bop(tmp_path / "names")


def test_load_object_set_dispatches(tmp_path):
    assert assets.load_object_set("builtin") is assets.builtin_object_set()
    _write_class_folder(tmp_path / "folder")
    assert assets.load_object_set(str(tmp_path / "folder"), scale=0.001, surface_samples=16).classes == (
        "block", "tin")
    with pytest.raises(FileNotFoundError, match="absent"):
        assets.load_object_set(str(tmp_path / "absent"))


def test_load_object_set_names_a_missing_bop_models_info(tmp_path):
    """BOP models without models_info.json are an error naming the missing file, not a class "models"."""
    _write_bop(tmp_path / "lm")
    (tmp_path / "lm" / "models" / "models_info.json").unlink()
    missing = tmp_path / "lm" / "models" / "models_info.json"
    for source in (tmp_path / "lm", tmp_path / "lm" / "models"):
        with pytest.raises(FileNotFoundError, match=re.escape(str(missing))) as error:
            assets.load_object_set(str(source), surface_samples=16)
        assert "obj_*.ply" in str(error.value)
    with pytest.raises(FileNotFoundError, match=re.escape(str(missing))):
        assets.object_set_from_config(assets.ObjectSetConfig(source=str(tmp_path / "lm"), scale=0.001))
    # A class folder may still have a class named "models", as long as it holds no BOP model files.
    (tmp_path / "own" / "models").mkdir(parents=True)
    trimesh.creation.box(extents=[0.05, 0.05, 0.05]).export(tmp_path / "own" / "models" / "cube.stl")
    assert assets.load_object_set(str(tmp_path / "own"), surface_samples=16).classes == ("models",)


def test_max_distance_is_the_largest_vertex_distance():
    rng = np.random.default_rng(0)
    for vertices in (rng.normal(size=(300, 3)), np.array([[0.0, 0, 0], [1, 0, 0], [3, 0, 0]]),  # collinear
                     np.c_[rng.normal(size=(50, 2)), np.zeros(50)], np.zeros((1, 3))):  # coplanar, one point
        brute = np.linalg.norm(vertices[:, None] - vertices[None], axis=-1).max()
        assert assets._max_distance(vertices) == pytest.approx(brute, rel=1e-12)


@pytest.mark.parametrize(("field", "value", "rule"), [
    ("surface_samples", 0, ">= 1"), ("train_per_class", -1, ">= 0"), ("test_per_class", -1, ">= 0"),
    ("seed", -3, ">= 0"), ("test_fraction", 1.0, "in [0, 1)"), ("test_fraction", -0.1, "in [0, 1)"),
    ("scale", 0.0, "positive"), ("scale", float("inf"), "positive"), ("up_axis", "w", "one of"),
])
def test_object_set_config_rejects_out_of_range_values(tmp_path, field, value, rule):
    """In Python, on the command line and in a YAML file, the error names the key ``objects.<field>``."""
    with pytest.raises(ValueError, match=rf"objects\.{field} must be {re.escape(rule)}"):
        assets.ObjectSetConfig(**{field: value})

    @dataclasses.dataclass(frozen=True)
    class Run:
        name: str = "run"
        objects: assets.ObjectSetConfig = dataclasses.field(default_factory=assets.ObjectSetConfig)

    with pytest.raises(config.ConfigError, match=rf"command line: objects\.{field} must be {re.escape(rule)}"):
        config.load_config(Run, overrides=[f"objects.{field}={value}"])
    path = tmp_path / "run.yaml"
    path.write_text(f"objects:\n  {field}: {value}\n")
    with pytest.raises(config.ConfigError, match=rf"{re.escape(str(path))}: objects\.{field} must be"):
        config.load_config(Run, path)


def test_objects_package_imports_stay_one_way():
    """The object-set modules import only the standard library, NumPy, SciPy, trimesh, each other and jaxcls's
    host cache (``compile_cache``: the standard library at import; ``kept_on_disk``); building a set, JAX is not
    imported."""
    import ast
    import subprocess
    import sys

    allowed = {"numpy", "scipy", "trimesh", "__future__"} | set(sys.stdlib_module_names)
    package = Path(assets.__file__).parent
    for file in sorted(package.glob("*.py")):
        for node in ast.walk(ast.parse(file.read_text())):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names if node.module == "jaxcls"]
            else:
                continue
            names = [n for n in names if n != "jaxcls"]  # (``from jaxcls import x``: x is checked)
            for name in names:
                assert (name.startswith("jaxcls.world.objects.") or name == "jaxcls.compile_cache"
                        or name.split(".")[0] in allowed), (file, name)
    built = subprocess.run([sys.executable, "-c", "import sys\nfrom jaxcls.world.objects import builtin_object_set\n"
                            "builtin_object_set(train_per_class=1, test_per_class=0, surface_samples=16)\n"
                            "print(sorted(m for m in ('jax', 'jaxlib', 'flax') if m in sys.modules))"],
                           capture_output=True, text=True, timeout=120)
    assert built.returncode == 0 and built.stdout.strip() == "[]", (built.stdout, built.stderr)


def test_object_set_config_round_trips_and_dispatches(tmp_path):
    default = assets.ObjectSetConfig()
    assert assets.ObjectSetConfig(**dataclasses.asdict(default)) == default
    assert assets.object_set_from_config(default) is assets.builtin_object_set()
    assert config.load_config(assets.ObjectSetConfig, overrides=["source=x", "scale=0.001"]) == (
        assets.ObjectSetConfig(source="x", scale=0.001))

    _write_class_folder(tmp_path / "folder")
    folder = assets.ObjectSetConfig(source=str(tmp_path / "folder"), scale=0.001, up_axis="y",
                                    surface_samples=16)
    objects = assets.object_set_from_config(folder)
    np.testing.assert_allclose(np.ptp(objects.train[2].mesh.vertices, axis=0), [0.09, 0.05, 0.05], atol=1e-9)

    _write_bop(tmp_path / "bop")
    with pytest.raises(ValueError, match=r"\['scale'\]"):
        assets.ObjectSetConfig(source=str(tmp_path / "bop"), scale=0.001).loader_kwargs()
    with pytest.raises(ValueError, match=r"\['test_fraction'\]"):
        assets.ObjectSetConfig(test_fraction=0.25).loader_kwargs()
