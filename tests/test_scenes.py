import dataclasses
import json
import math

import mujoco
import numpy as np
import pytest

from jaxcls import geometry
from jaxcls.world import scenes
from jaxcls.world.objects import ObjectSetConfig, builtin_object_set


@pytest.fixture(scope="module")
def object_set():
    return builtin_object_set()


def _hulls(scene, object_set):
    models = scenes.scene_models(scene, object_set)
    return [scenes._place_footprint(m.footprint(), np.array(o.position), o.yaw)
            for o, m in zip(scene.objects, models, strict=True)]


def test_same_seed_same_scene(object_set):
    cfg = scenes.SceneConfig()
    a, b = (scenes.sample_scene(object_set, cfg, seed=11) for _ in range(2))
    assert a == b
    assert scenes.sample_scene(object_set, cfg, seed=12) != a


def test_scene_draws_from_the_split_with_distinct_classes(object_set):
    scene = scenes.sample_scene(object_set, scenes.SceneConfig(num_objects=5, num_clutter=2), seed=3)
    test_names = {m.name for m in object_set.test}
    assert all(o.name in test_names for o in scene.objects)
    assert len({o.class_name for o in scene.objects}) == 5
    assert sum(o.target for o in scene.objects) == 3


def test_footprint_separation_is_a_signed_gap():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    assert scenes.footprint_separation(square, square + np.array([1.5, 0])) == pytest.approx(0.5)
    assert scenes.footprint_separation(square, square + np.array([0.5, 0.5])) < 0
    # Diagonal neighbours: SAT gives a lower bound of the Euclidean distance sqrt(2) * 0.5.
    gap = scenes.footprint_separation(square, square + np.array([1.5, 1.5]))
    assert 0 < gap <= math.sqrt(2) * 0.5 + 1e-9


@pytest.mark.parametrize(("min_gap", "max_gap"), [(0.003, 0.03), (0.001, 0.005)])
def test_no_interpenetration_and_clutter_over_many_seeds(object_set, min_gap, max_gap):
    cfg = scenes.SceneConfig(min_gap=min_gap, max_gap=max_gap)
    for seed in range(25):
        scene = scenes.sample_scene(object_set, cfg, seed)
        hulls = _hulls(scene, object_set)
        n = len(hulls)
        sep = np.full((n, n), np.inf)
        for i in range(n):
            for j in range(i + 1, n):
                sep[i, j] = sep[j, i] = scenes.footprint_separation(hulls[i], hulls[j])
        assert sep.min() >= min_gap - 1e-9, f"seed {seed}: footprints overlap ({sep.min():.4f} m)"
        # Clutter: every object stands within the largest gap (plus the slide step) of a neighbour.
        assert sep.min(axis=1).max() <= max_gap + 0.0021, f"seed {seed}: an object stands apart"
        # The peer: MuJoCo's own collision distance between the object meshes.
        dist = scenes.object_distances(scenes.build_model(scene, scenes.scene_models(scene, object_set),
                                                          geometry.Intrinsics.kinect_v1(0.1)))
        assert dist.min() > 0, f"seed {seed}: MuJoCo finds interpenetration ({dist.min():.4f} m)"


def test_json_round_trip(tmp_path, object_set):
    scene = scenes.sample_scene(object_set, scenes.SceneConfig(num_clutter=2), seed=5)
    path = scene.save(tmp_path / "scene.json")
    loaded = scenes.Scene.load(path)
    assert loaded == scene
    np.testing.assert_array_equal(loaded.object_poses(), scene.object_poses())
    data = json.loads(path.read_text())
    assert data["format"] == "jaxcls-scene" and len(data["objects"]) == 5
    # The JSON alone rebuilds the scene: the object set comes from its config.
    models = scenes.scene_models(loaded)
    assert [m.name for m in models] == [o.name for o in scene.objects]


@pytest.mark.parametrize(("edit", "match"), [
    (lambda d: d.pop("objects"), "objects"),
    (lambda d: d["objects"][1].pop("yaw"), r"objects\[1\]\.yaw"),
    (lambda d: d.update(format="other"), "format"),
    (lambda d: d["objects"][0].update(position=[1.0]), "position"),
    (lambda d: d["objects"][0].update(position=5), r"objects\[0\]\.position"),
    (lambda d: d["objects"][2].update(yaw=float("nan")), r"objects\[2\]\.yaw.*finite"),
    (lambda d: d.update(version=99), "version"),
    (lambda d: d.update(seed="x"), "seed"),
    (lambda d: d.update(table_height="abc"), "table_height"),
])
def test_bad_scene_json_names_the_key(tmp_path, object_set, edit, match):
    data = scenes.sample_scene(object_set, scenes.SceneConfig(), seed=1).to_dict()
    edit(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=match):
        scenes.Scene.load(path)


def test_unknown_instance_is_a_clear_error(object_set):
    scene = scenes.sample_scene(object_set, scenes.SceneConfig(), seed=1)
    renamed = dataclasses.replace(scene, objects=(dataclasses.replace(scene.objects[0], name="teapot_9"),
                                                  *scene.objects[1:]))
    with pytest.raises(ValueError, match="teapot_9"):
        scenes.scene_models(renamed, object_set)


def test_model_follows_the_renderer_contract(object_set):
    cfg = scenes.SceneConfig(table_height=0.7)
    scene = scenes.sample_scene(object_set, cfg, seed=2)
    intr = geometry.Intrinsics.kinect_v1()
    model = scenes.build_model(scene, scenes.scene_models(scene, object_set), intr)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    table = model.geom("table")
    assert data.geom_xpos[table.id][2] + table.size[2] == pytest.approx(0.7)
    cam_body = model.body("camera")
    assert cam_body.mocapid[0] >= 0
    cam = model.camera("depth")
    assert cam.bodyid[0] == cam_body.id
    assert model.cam_fovy[cam.id] == pytest.approx(intr.fovy_deg)
    np.testing.assert_array_equal(model.cam_resolution[cam.id], [640, 480])
    models = scenes.scene_models(scene, object_set)
    for i, (obj, m) in enumerate(zip(scene.objects, models, strict=True)):
        geom = model.geom(f"object_{i}")
        assert model.geom_bodyid[geom.id] == model.body(f"object_{i}").id
        assert model.geom_matid[geom.id] >= 0
        # Every object rests on the table: its lowest world vertex is at the table height.
        vert = model.mesh_vert[model.mesh_vertadr[geom.dataid[0]]:][:model.mesh_vertnum[geom.dataid[0]]]
        world = vert @ data.geom_xmat[geom.id].reshape(3, 3).T + data.geom_xpos[geom.id]
        assert world[:, 2].min() == pytest.approx(0.7, abs=1e-5)
        expected = m.mesh.vertices @ scene.object_poses()[i][:3, :3].T + scene.object_poses()[i][:3, 3]
        np.testing.assert_allclose(np.sort(world[:, 0]), np.sort(expected[:, 0]), atol=1e-5)
        del obj


def test_centroid_is_the_mean_of_object_centres(object_set):
    scene = scenes.sample_scene(object_set, scenes.SceneConfig(), seed=4)
    models = scenes.scene_models(scene, object_set)
    centroid = scenes.scene_centroid(scene, models)
    assert abs(centroid[0]) < 0.05 and abs(centroid[1]) < 0.05  # the cluster is centred on the table
    assert 0.02 < centroid[2] < 0.12


def test_objects_must_fit_on_the_table(object_set):
    with pytest.raises(ValueError, match="table_half_size"):
        scenes.sample_scene(object_set, scenes.SceneConfig(table_half_size=0.05), 0)


def test_image_axes_follow_the_world(object_set):
    """An absolute check of the camera convention, independent of pixel_rays: from straight above
    (image right = world +x, image down = world -y), an object at +x lands right of centre, one at -y
    below it; from the side, the far table is higher in the image than the near table."""
    from jaxcls.world.render import make_renderer

    scene = scenes.sample_scene(object_set, scenes.SceneConfig(num_objects=2), seed=0)
    scene = dataclasses.replace(scene, objects=(dataclasses.replace(scene.objects[0], position=(0.2, 0.0)),
                                                dataclasses.replace(scene.objects[1], position=(0.0, -0.2))))
    models = scenes.scene_models(scene, object_set)
    intr = geometry.Intrinsics.kinect_v1(0.25)
    renderer = make_renderer(scenes.build_model(scene, models, intr), intr, "mujoco")
    top = geometry.look_at([0, 0, 1.0], [0, 0, 0])
    side = geometry.look_at([0, -1.0, 0.5], [0, 0, 0])
    frames = renderer.render(np.stack([top, side]))
    v, u = np.nonzero(frames.object_id[0] == 0)
    assert u.mean() > intr.cx + 10 and abs(v.mean() - intr.cy) < 5
    v, u = np.nonzero(frames.object_id[0] == 1)
    assert v.mean() > intr.cy + 10 and abs(u.mean() - intr.cx) < 5
    column = frames.depth[1][:, intr.width // 2]
    rows = np.nonzero(column > 0)[0]
    assert column[rows[0]] > column[rows[-1]]  # top rows see farther


def test_bad_scene_config(object_set):
    with pytest.raises(ValueError, match="num_clutter"):
        scenes.sample_scene(object_set, scenes.SceneConfig(num_objects=3, num_clutter=4), 0)
    with pytest.raises(ValueError, match="min_gap"):
        scenes.sample_scene(object_set, scenes.SceneConfig(min_gap=0.0), 0)
    assert ObjectSetConfig().source == "builtin"


def test_occlusion_counts(object_set):
    """Objects in clutter hide each other from some views; alone, nothing is hidden."""
    scene = scenes.sample_scene(object_set, scenes.SceneConfig(), seed=0)
    models = scenes.scene_models(scene, object_set)
    intr = geometry.Intrinsics.kinect_v1(0.25)
    T_wc = geometry.hemisphere_viewpoints(scenes.scene_centroid(scene, models), 24, 1.0)
    seen, alone = scenes.occlusion_counts(scene, models, intr, T_wc)
    assert seen.shape == alone.shape == (24, 5)
    assert (seen <= alone).all()
    fraction = seen[alone > 0] / alone[alone > 0]
    assert fraction.min() < 0.75  # some object loses over a quarter of its pixels in some view
    assert np.median(fraction) > 0.5
    single = dataclasses.replace(scene, objects=scene.objects[:1])
    seen1, alone1 = scenes.occlusion_counts(single, models[:1], intr, T_wc)
    np.testing.assert_array_equal(seen1, alone1)


def test_builtin_scene_renders_alike_in_mujoco_and_mjx(object_set):
    """The peer check on a real scene: MJX's ray casting against MuJoCo's C caster, ids included."""
    from jaxcls.world.render import make_renderer

    scene = scenes.sample_scene(object_set, scenes.SceneConfig(), seed=3)
    models = scenes.scene_models(scene, object_set)
    intr = geometry.Intrinsics.kinect_v1(0.1)
    model = scenes.build_model(scene, models, intr)
    T_wc = geometry.hemisphere_viewpoints(scenes.scene_centroid(scene, models), 100, 1.0)[[23, 58, 91]]
    ref = make_renderer(model, intr, "mujoco").render(T_wc)
    out = make_renderer(model, intr, "mjx").render(T_wc)
    ref_depth, out_depth = np.asarray(ref.depth), np.asarray(out.depth)
    both = (ref_depth > 0) & (out_depth > 0)
    assert both.sum() > 0.5 * both.size
    assert np.mean(np.abs(ref_depth[both] - out_depth[both]) < 1e-3) >= 0.995
    ref_id, out_id = np.asarray(ref.object_id), np.asarray(out.object_id)
    assert np.mean(ref_id[both] == out_id[both]) >= 0.995
    assert (ref_id >= 0).sum() > 50  # the objects are in view, not just the table


def test_sliding_in_skips_only_steps_that_cannot_clear():
    """``_slide_in`` skips the steps the separation's Lipschitz bound rules out: the first clearing step of the
    plain march, bit for bit (the scenes of every seed stay what they were)."""
    def marched(hull, yaw, placed, anchor, direction, gap, step=0.002):
        d = np.array([math.cos(direction), math.sin(direction)])
        t = 0.0
        while True:
            position = anchor + t * d
            moved = scenes._place_footprint(hull, position, yaw)
            if min(scenes.footprint_separation(moved, h) for h in placed) >= gap:
                return position
            t += step

    rng = np.random.default_rng(0)
    hulls = [m.footprint() for m in builtin_object_set().split("all")[:8]]
    for _ in range(60):
        placed = [scenes._place_footprint(hulls[i], rng.uniform(-0.1, 0.1, 2), rng.uniform(-math.pi, math.pi))
                  for i in rng.choice(len(hulls), 3, replace=False)]
        args = (hulls[rng.integers(len(hulls))], rng.uniform(-math.pi, math.pi), placed, rng.uniform(-0.05, 0.05, 2),
                rng.uniform(0, 2 * math.pi), rng.uniform(0.0, 0.02))
        assert np.array_equal(scenes._slide_in(*args), marched(*args))
