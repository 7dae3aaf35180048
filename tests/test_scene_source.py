"""The "scene" training source: observe's segments of cluttered scenes, labelled by their majority
object; cached per scene and resumed like the per-instance sources."""

from __future__ import annotations

import numpy as np
import pytest

from jaxcls.learn import clouds
from jaxcls.perception.settings import PerceptionConfig, ShapeConfig
from jaxcls.world.objects import ObjectSetConfig, builtin_object_set

OBJECTS = ObjectSetConfig(train_per_class=1, test_per_class=0)
PERCEPTION = PerceptionConfig(shapes=ShapeConfig(surface_points=8192, points_per_segment=512))


def _config(tmp_path, scenes=2):
    return clouds.CloudConfig(full_per_instance=0, views_per_instance=0, occluded_per_instance=0,
                              fused_per_instance=0, scenes=scenes, scene_max_views=2, max_points=512,
                              image_scale=0.5, backend="mujoco", cache_dir=str(tmp_path))


def test_scene_clouds_are_pure_labelled_segments_and_resume(tmp_path, monkeypatch):
    object_set = builtin_object_set(train_per_class=1, test_per_class=0)
    config = _config(tmp_path)
    made = []
    real = clouds.scene_clouds

    def counting(*args, **kwargs):
        made.append(args[4])
        return real(*args, **kwargs)

    monkeypatch.setattr(clouds, "scene_clouds", counting)
    first = clouds.load_clouds(object_set, "train", config, OBJECTS, seed=0, show_progress=False,
                               perception=PERCEPTION)
    assert len(made) == 2 and len(first) >= 4  # most of each scene's 5 objects become a pure segment
    assert np.all(first.source == clouds.SOURCES.index("scene"))
    assert set(first.label.tolist()) <= set(range(len(object_set.classes)))
    counts = first.mask.sum(axis=1)
    assert np.all((counts >= config.min_points) & (counts <= config.max_points))
    np.testing.assert_allclose(first.points[first.mask].reshape(-1, 3).mean(0), 0.0, atol=0.01)  # centred
    # Each label is its instance's class: the instance index points at a model of that class.
    for label, instance in zip(first.label, first.instance, strict=True):
        assert object_set.classes[label] == object_set.train[instance].class_name
    # Cached: nothing is made again, the same clouds come back.
    again = clouds.load_clouds(object_set, "train", config, OBJECTS, seed=0, show_progress=False,
                               perception=PERCEPTION)
    assert len(made) == 2
    np.testing.assert_array_equal(again.points, first.points)
    # Interrupted: a missing scene file is made again, alone, identically.
    scene_files = sorted(tmp_path.rglob("scene_*.npz"))
    assert len(scene_files) == 2
    scene_files[1].unlink()
    resumed = clouds.load_clouds(object_set, "train", config, OBJECTS, seed=0, show_progress=False,
                                 perception=PERCEPTION)
    assert len(made) == 3
    np.testing.assert_array_equal(resumed.points, first.points)
    # More scenes extend the same cache; a changed segmentation gets a folder of its own.
    clouds.load_clouds(object_set, "train", _config(tmp_path, scenes=3), OBJECTS, seed=0, show_progress=False,
                       perception=PERCEPTION)
    assert len(made) == 4
    from jaxcls.perception.settings import SegmentConfig

    other = PerceptionConfig(shapes=PERCEPTION.shapes, segmentation=SegmentConfig(dbscan_eps=0.012))
    clouds.load_clouds(object_set, "train", _config(tmp_path, scenes=1), OBJECTS, seed=0, show_progress=False,
                       perception=other)
    assert len(made) == 5


def test_a_mix_of_the_scene_source_needs_its_clouds():
    from jaxcls.learn.train import Mix, make_bank

    empty = clouds.CloudSet(np.zeros((2, 4, 3), np.float32), np.ones((2, 4), bool), np.zeros(2, np.int32),
                            np.zeros(2, np.int32), np.zeros(2, np.int32), np.zeros(2, np.float32))
    with pytest.raises(ValueError, match=r"mix\.scene"):
        make_bank(empty, Mix(full=1.0, scene=0.5))


@pytest.mark.parametrize(("touching", "noisy"), [(1.0, 0.0), (0.0, 1.0), (0.0, 0.0)])
def test_scene_source_draws_touching_and_noisy_scenes(tmp_path, monkeypatch, touching, noisy):
    """scene_touching / scene_noisy pick the world a scene is drawn in: gaps of 1-5 mm, or the sensor model
    with hand-eye error; the segments still come out labelled."""
    from jaxcls.world import setup

    object_set = builtin_object_set(train_per_class=1, test_per_class=0)
    config = clouds.CloudConfig(**{**_config(tmp_path, scenes=1).__dict__, "scene_touching": touching,
                                   "scene_noisy": noisy})
    worlds = []
    real = setup.make_world

    def capture(*args, **kwargs):
        worlds.append(real(*args, **kwargs))
        return worlds[-1]

    monkeypatch.setattr(setup, "make_world", capture)
    part = clouds.scene_clouds(object_set, "train", OBJECTS, config, seed=3, perception=PERCEPTION)
    (world,) = worlds
    gaps = (world.config.scene.min_gap, world.config.scene.max_gap)
    assert gaps == ((0.001, 0.005) if touching else (0.003, 0.03))
    sensor = world.config.sensor
    assert sensor.axial_noise == sensor.pose_noise == bool(noisy)
    assert len(part) >= 3 and np.all(part.source == clouds.SOURCES.index("scene"))


def test_scene_fractions_are_checked():
    with pytest.raises(ValueError, match="scene_touching"):
        clouds.CloudConfig(scenes=1, scene_touching=0.7, scene_noisy=0.5)


def test_worker_processes_make_the_same_clouds(tmp_path):
    """``data.workers`` 2: the missing instances' and scenes' files made by two spawned processes (the object set
    made again from its config in each) hold the clouds one process makes; an object set the config does not
    make is refused with a clear error."""
    object_set = builtin_object_set(train_per_class=1, test_per_class=0)
    base = {**_config(tmp_path).__dict__, "views_per_instance": 1}
    one = clouds.load_clouds(object_set, "train", clouds.CloudConfig(**{**base, "cache_dir": str(tmp_path / "a")}),
                             OBJECTS, seed=0, show_progress=False, perception=PERCEPTION)
    two = clouds.load_clouds(object_set, "train", clouds.CloudConfig(**{**base, "cache_dir": str(tmp_path / "b"),
                                                                        "workers": 2}),
                             OBJECTS, seed=0, show_progress=False, perception=PERCEPTION)
    assert len(one) > len(object_set.train) and set(one.source.tolist()) == {clouds.SOURCES.index("view"),
                                                                              clouds.SOURCES.index("scene")}
    for field in ("points", "mask", "label", "source", "instance", "yaw"):
        np.testing.assert_array_equal(getattr(two, field), getattr(one, field), err_msg=field)
    other = builtin_object_set(train_per_class=2, test_per_class=0)  # not what OBJECTS makes
    with pytest.raises(ValueError, match="remakes the object set"):
        clouds.load_clouds(other, "train", clouds.CloudConfig(**{**base, "cache_dir": str(tmp_path / "c"),
                                                                 "workers": 2, "scenes": 0}),
                           OBJECTS, seed=0, show_progress=False, perception=PERCEPTION)
