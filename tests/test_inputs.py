"""Bad inputs fail early with a message that names the key, the file or the shapes, never silently."""

import json

import jax.numpy as jnp
import numpy as np
import pytest

from jaxcls import geometry
from jaxcls.config import ConfigError, load_config
from jaxcls.geometry import CameraConfig, Intrinsics, ViewpointConfig
from jaxcls.perception import foreground, init_state, observe, pointnet, segment, tsdf
from jaxcls.perception.settings import Spec
from jaxcls.world import scenes
from jaxcls.world.dataset import DatasetConfig
from jaxcls.world.objects import builtin_object_set
from jaxcls.world.render.sensor import SensorConfig

SMALL_INTRINSICS = Intrinsics(width=16, height=12, fx=13.0, fy=13.0, cx=7.5, cy=5.5)


# ---------------------------------------------------------------------------------------------- config ranges

def test_sensor_ranges_from_the_command_line_and_from_python():
    with pytest.raises(ConfigError, match=r"command line: key 'sensor\.random_dropout' must be <= 1"):
        load_config(DatasetConfig, overrides=["sensor.random_dropout=1.5"])
    with pytest.raises(ConfigError, match=r"key 'sensor\.sigma_base' must be >= 0"):
        load_config(DatasetConfig, overrides=["sensor.sigma_base=-1"])
    with pytest.raises(ValueError, match=r"sensor\.random_dropout must be <= 1"):
        SensorConfig(random_dropout=1.5)
    with pytest.raises(ValueError, match=r"sensor\.sigma_base"):
        SensorConfig(sigma_base=-1.0)


@pytest.mark.parametrize(("override", "key"), [
    ("sensor.edge_prob=-0.1", "sensor.edge_prob"),
    ("sensor.subpixel=0", "sensor.subpixel"),
    ("sensor.edge_width=0", "sensor.edge_width"),
    ("sensor.max_incidence_deg=95", "sensor.max_incidence_deg"),
    ("sensor.max_incidence_deg=0", "sensor.max_incidence_deg"),
    ("sensor.min_depth=0", "sensor.min_depth"),
    ("sensor.pose_trans_sigma=-0.001", "sensor.pose_trans_sigma"),
    ("scene.num_objects=0", "scene.num_objects"),
    ("scene.num_clutter=-1", "scene.num_clutter"),
    ("scene.min_gap=0", "scene.min_gap"),
    ("scene.table_half_size=0", "scene.table_half_size"),
    ("scene.table_height=inf", "scene.table_height"),
    ("camera.width=0", "camera.width"),
    ("camera.fx=-525", "camera.fx"),
    ("camera.cy=nan", "camera.cy"),
    ("viewpoints.count=0", "viewpoints.count"),
    ("viewpoints.radius=0", "viewpoints.radius"),
    ("viewpoints.min_elevation_deg=90", "viewpoints.min_elevation_deg"),
])
def test_world_ranges_name_the_dotted_key(override, key):
    with pytest.raises(ConfigError, match=rf"command line: key '{key}'"):
        load_config(DatasetConfig, overrides=[override])


@pytest.mark.parametrize(("overrides", "keys"), [
    (["sensor.min_depth=5", "sensor.max_depth=4"], ("sensor.min_depth", "sensor.max_depth")),
    (["scene.num_objects=3", "scene.num_clutter=4"], ("scene.num_clutter", "scene.num_objects")),
    (["scene.min_gap=0.05", "scene.max_gap=0.01"], ("scene.min_gap", "scene.max_gap")),
])
def test_cross_field_rules_name_both_keys(overrides, keys):
    with pytest.raises(ConfigError, match="command line") as error:
        load_config(DatasetConfig, overrides=overrides)
    assert all(key in str(error.value) for key in keys)


def test_world_ranges_from_python():
    with pytest.raises(ValueError, match=r"scene\.num_objects"):
        scenes.SceneConfig(num_objects=0)
    with pytest.raises(ValueError, match=r"scene\.num_clutter"):
        scenes.SceneConfig(num_objects=2, num_clutter=3)
    with pytest.raises(ValueError, match=r"camera\.height"):
        CameraConfig(height=0)
    with pytest.raises(ValueError, match=r"viewpoints\.min_elevation_deg"):
        ViewpointConfig(min_elevation_deg=-5.0)


def test_training_ranges_name_the_dotted_key():
    from jaxcls.learn.clouds import CloudConfig
    from jaxcls.learn.train import Mix, TrainConfig

    for override, key in [("data.max_points=0", "data.max_points"), ("data.radius=[0,1]", "data.radius"),
                          ("data.elevation_deg=[10,100]", "data.elevation_deg"),
                          ("data.image_scale=0", "data.image_scale"), ("mix.view=-1", "mix.view"),
                          ("model.dropout=1", "model.dropout"), ("model.num_points=0", "model.num_points"),
                          ("model.bn_momentum=1.5", "model.bn_momentum"),
                          ("model.feature_transform_weight=-1", "model.feature_transform_weight"),
                          ("epochs=0", "epochs"), ("learning_rate=0", "learning_rate"), ("jitter=-1", "jitter")]:
        with pytest.raises(ConfigError, match=rf"command line: key '{key}'"):
            load_config(TrainConfig, overrides=[override])
    with pytest.raises(ConfigError, match=r"data\.radius.*low <= high"):
        load_config(TrainConfig, overrides=["data.radius=[1.2,0.7]"])
    with pytest.raises(ConfigError, match="mix weights"):
        load_config(TrainConfig, overrides=["mix.full=0"])
    with pytest.raises(ValueError, match=r"model\.dropout"):
        pointnet.ModelConfig(dropout=1.0)
    with pytest.raises(ValueError, match=r"mix\.fused"):
        Mix(fused=-0.5)
    with pytest.raises(ValueError, match=r"data\.min_points"):
        CloudConfig(min_points=0)


def test_empty_yaml_names_the_file(tmp_path):
    path = tmp_path / "empty.yaml"
    path.write_text("")
    with pytest.raises(ConfigError, match=r"empty\.yaml.*empty"):
        load_config(DatasetConfig, path)


# ---------------------------------------------------------------------------------------------- scenes

def test_too_many_objects_for_the_split_is_an_error_naming_the_fix():
    objects = builtin_object_set(train_per_class=1, test_per_class=1)  # 8 classes x 1 held-out instance
    with pytest.raises(ValueError, match=r"scene\.num_objects = 9") as error:
        scenes.sample_scene(objects, scenes.SceneConfig(num_objects=9), seed=0)
    message = str(error.value)
    assert "8 instances" in message and "'test'" in message
    assert "scene.split=all" in message and "scene.distinct_classes=false" in message


def test_distinct_draw_never_repeats_an_instance_and_spreads_classes():
    objects = builtin_object_set(train_per_class=1, test_per_class=2)  # 16 held-out instances
    scene = scenes.sample_scene(objects, scenes.SceneConfig(num_objects=10), seed=0)
    names = [o.name for o in scene.objects]
    assert len(set(names)) == 10
    assert {o.class_name for o in scene.objects} == set(objects.classes)  # every class before any twice


def test_non_distinct_draw_may_repeat_instances():
    """distinct_classes=false asks for a draw with replacement: more objects than instances is allowed."""
    objects = builtin_object_set(train_per_class=1, test_per_class=1)
    config = scenes.SceneConfig(num_objects=12, distinct_classes=False)
    scene = scenes.sample_scene(objects, config, seed=0)
    assert scene.num_objects == 12 and len({o.name for o in scene.objects}) < 12


def test_scene_save_is_atomic_json(tmp_path):
    objects = builtin_object_set()
    scene = scenes.sample_scene(objects, scenes.SceneConfig(num_objects=2), seed=0)
    path = scene.save(tmp_path / "sub" / "scene.json")
    assert scenes.Scene.load(path) == scene
    assert [p.name for p in path.parent.iterdir()] == ["scene.json"]  # no temporary file left


# ---------------------------------------------------------------------------------------------- intrinsics

@pytest.mark.parametrize(("field", "value"), [
    ("width", 0), ("height", -3), ("width", 64.0), ("fx", 0.0), ("fy", -1.0), ("fx", float("nan")),
    ("cx", float("inf")), ("cy", "12"),
])
def test_intrinsics_from_python_name_the_field(field, value):
    kwargs = dict(width=16, height=12, fx=13.0, fy=13.0, cx=7.5, cy=5.5)
    kwargs[field] = value
    with pytest.raises(ValueError, match=rf"Intrinsics: {field} must be"):
        Intrinsics(**kwargs)


def test_intrinsics_accept_numpy_numbers():
    k = Intrinsics(width=np.int64(16), height=12, fx=np.float32(13.0), fy=13.0, cx=7.5, cy=5.5)
    assert k.width == 16


# ---------------------------------------------------------------------------------------------- weights

def _weights(tmp_path):
    """A copy of the shipped weights' files in ``tmp_path`` (the .json can then be spoilt)."""
    path = tmp_path / "w.msgpack"
    path.write_bytes(pointnet.BUILTIN_WEIGHTS.read_bytes())
    path.with_suffix(".json").write_text(pointnet.BUILTIN_WEIGHTS.with_suffix(".json").read_text())
    return path


def test_corrupt_weights_json_names_the_file(tmp_path):
    path = _weights(tmp_path)
    path.with_suffix(".json").write_text('{"classes": ["a", ')
    with pytest.raises(ValueError, match=r"w\.json: not valid JSON \("):
        pointnet.load_classifier(path)


@pytest.mark.parametrize("classes", ["mug", [1, 2], [], None, ["mug", "mug"]])
def test_weights_json_classes_must_be_names(tmp_path, classes):
    path = _weights(tmp_path)
    info = json.loads(path.with_suffix(".json").read_text())
    info["classes"] = classes
    if classes is None:
        del info["classes"]
    path.with_suffix(".json").write_text(json.dumps(info))
    with pytest.raises(ValueError, match=r"w\.json: 'classes'"):
        pointnet.load_classifier(path)


def test_weights_json_model_out_of_range_names_the_file(tmp_path):
    path = _weights(tmp_path)
    info = json.loads(path.with_suffix(".json").read_text())
    info["model"]["dropout"] = 2.0
    path.with_suffix(".json").write_text(json.dumps(info))
    with pytest.raises(ValueError, match=r"w\.json: 'model'.*model\.dropout"):
        pointnet.load_classifier(path)


def test_weights_for_another_class_count_name_the_layer(tmp_path):
    path = _weights(tmp_path)
    info = json.loads(path.with_suffix(".json").read_text())
    info["classes"] = ["a", "b", "c"]  # the .msgpack holds 8 classes' output layer
    path.with_suffix(".json").write_text(json.dumps(info))
    layer = r"w\.msgpack: .*\['bias'\] has shape \(8,\), expected \(3,\) for PointNet weights for the 3 classes"
    with pytest.raises(ValueError, match=layer):
        pointnet.load_classifier(path)


# ---------------------------------------------------------------------------------------------- shapes

@pytest.fixture(scope="module")
def classifier():
    return pointnet.load_classifier()


def test_classify_checks_shapes(classifier):
    with pytest.raises(ValueError, match=r"\[N, P, 3\].*\(2, 64, 2\)"):
        pointnet.classify(classifier, jnp.zeros((2, 64, 2)), jnp.ones((2, 64), bool))
    with pytest.raises(ValueError, match=r"\[N, P, 3\].*\(64, 3\)"):
        pointnet.classify(classifier, jnp.zeros((64, 3)), jnp.ones(64, bool))
    with pytest.raises(ValueError, match=r"mask must be \[N, P\] = \[2, 64\].*\(2, 63\)"):
        pointnet.classify(classifier, jnp.zeros((2, 64, 3)), jnp.ones((2, 63), bool))
    probs = pointnet.classify(classifier, jnp.zeros((2, 64, 3)), jnp.zeros((2, 64), bool))
    assert probs.shape == (2, len(classifier.classes))


def test_segment_jax_checks_shapes():
    spec = Spec.create()
    points, normals, mask = jnp.zeros((100, 3)), jnp.zeros((100, 3)), jnp.ones(100, bool)
    with pytest.raises(ValueError, match=r"points must be \[P, 3\].*\(100, 2\)"):
        segment.segment_jax(spec, jnp.zeros((100, 2)), normals, mask)
    with pytest.raises(ValueError, match=r"mask must be \[P\] = \[100\].*\(99,\)"):
        segment.segment_jax(spec, points, normals, jnp.ones(99, bool))


def _volume():
    return tsdf.create_volume(np.zeros(3), size=0.4, resolution=8)


def test_tsdf_check_frame_refuses_bad_poses():
    depth = jnp.ones((SMALL_INTRINSICS.height, SMALL_INTRINSICS.width))
    T = np.eye(4)
    T[2, 3] = 1.0
    nan_pose = T.copy()
    nan_pose[0, 3] = np.nan
    with pytest.raises(ValueError, match="not rigid"):
        tsdf.check_frame(depth, SMALL_INTRINSICS, jnp.asarray(nan_pose))
    scaled = T.copy()
    scaled[:3, :3] *= 1.5
    with pytest.raises(ValueError, match="not rigid"):
        tsdf.check_frame(depth, SMALL_INTRINSICS, jnp.asarray(scaled))


def test_wrong_depth_shape_names_the_shapes():
    T = jnp.eye(4)
    bad = jnp.ones((SMALL_INTRINSICS.width, SMALL_INTRINSICS.height))  # transposed
    with pytest.raises(ValueError, match=r"\(16, 12\).*\[12, 16\]"):
        tsdf.integrate(_volume(), bad, SMALL_INTRINSICS, T)
    spec = Spec.create(intrinsics=SMALL_INTRINSICS)
    with pytest.raises(ValueError, match=r"\(16, 12\).*\[12, 16\]"):
        foreground.foreground_depth(spec, bad, T)
    with pytest.raises(ValueError, match=r"T_wc must be \[4, 4\].*\(3, 4\)"):
        foreground.foreground_depth(spec, jnp.ones((12, 16)), T[:3])


def test_observe_checks_the_frame():
    spec = Spec.create(intrinsics=SMALL_INTRINSICS)
    with pytest.raises(ValueError, match=r"observe: depth has shape \(12, 15\)"):
        observe(spec, init_state(spec), jnp.ones((12, 15)), jnp.asarray(geometry.look_at([0, 0, 1.0], [0, 0, 0])))
