import numpy as np
import pytest

from jaxcls import geometry
from jaxcls.cli import main
from jaxcls.config import load_config
from jaxcls.world import dataset, recording, scenes
from jaxcls.world.render import SensorConfig, make_renderer

SMALL = ["camera.width=64", "camera.height=48", "camera.fx=52.5", "camera.fy=52.5", "camera.cx=31.5",
         "camera.cy=23.5", "viewpoints.count=6", "num_scenes=2", "batch_size=4", "backend=mujoco"]


def _config(tmp_path, path="configs/synthetic.yaml", extra=()):
    return load_config(dataset.DatasetConfig, path, [*SMALL, f"out_dir={tmp_path / 'ds'}", *extra])


def test_shipped_configs_load():
    synthetic = load_config(dataset.DatasetConfig, "configs/synthetic.yaml")
    assert (synthetic.num_scenes, synthetic.scene.num_objects, synthetic.viewpoints.count) == (7, 5, 100)
    assert synthetic.sensor == SensorConfig.ideal()
    real = load_config(dataset.DatasetConfig, "configs/real_like.yaml")
    assert (real.scene.num_objects, real.scene.num_clutter) == (5, 2)
    assert real.sensor.axial_noise and real.sensor.pose_noise


def test_dataset_matches_a_direct_render_and_resumes(tmp_path):
    cfg = _config(tmp_path)
    out = dataset.build_dataset(cfg, show_progress=False)
    files = sorted(out.glob("scene_*.npz"))
    assert [f.name for f in files] == ["scene_000.npz", "scene_001.npz"]
    assert (out / "config.yaml").is_file()
    views = dataset.SceneViews.load(files[1])
    assert views.depth.shape == (6, 48, 64) and views.object_id.shape == (6, 48, 64)
    assert views.depth.dtype == np.float32 and views.object_id.dtype == np.int32
    assert views.backend == "mujoco"
    # Ideal sensor: the stored frames are what the renderer gives for the stored poses.
    intr = cfg.camera.intrinsics()
    model = scenes.build_model(views.scene, scenes.scene_models(views.scene), intr)
    direct = make_renderer(model, intr, "mujoco").render(views.T_wc_true)
    np.testing.assert_array_equal(views.depth, np.asarray(direct.depth))
    np.testing.assert_array_equal(views.object_id, np.asarray(direct.object_id))
    np.testing.assert_array_equal(views.T_wc, views.T_wc_true)
    assert (views.object_id >= 0).any() and set(np.unique(views.object_id)) <= set(range(-1, 5))
    # The views look at the scene centroid from the hemisphere.
    centre = scenes.scene_centroid(views.scene, scenes.scene_models(views.scene))
    np.testing.assert_allclose(np.linalg.norm(views.T_wc[:, :3, 3] - centre, axis=1), 1.0, atol=1e-9)

    # Resume: a missing scene is rendered again, identically; finished ones are not touched.
    before = files[0].stat().st_mtime_ns
    depth1 = views.depth.copy()
    files[1].unlink()
    dataset.build_dataset(cfg, show_progress=False)
    assert files[0].stat().st_mtime_ns == before
    np.testing.assert_array_equal(dataset.SceneViews.load(files[1]).depth, depth1)


def test_worker_processes_write_what_one_process_writes(tmp_path):
    """``workers=2`` (scenes rendered in spawned processes, real-like sensor: noise and pose error drawn there)
    writes the same scene files as one process, and resumes the same way; a GPU-only backend is refused."""
    extra = ["num_scenes=3"]
    one = dataset.build_dataset(_config(tmp_path / "one", "configs/real_like.yaml", extra), show_progress=False)
    two = dataset.build_dataset(_config(tmp_path / "two", "configs/real_like.yaml", [*extra, "workers=2"]),
                                show_progress=False)
    (two / "scene_001.npz").unlink()
    dataset.build_dataset(_config(tmp_path / "two", "configs/real_like.yaml", [*extra, "workers=2"]),
                          show_progress=False)
    for i in range(3):
        a, b = (dataset.SceneViews.load(dataset.scene_file(d, i)) for d in (one, two))
        assert a.scene.to_dict() == b.scene.to_dict()
        for name in ("depth", "object_id", "T_wc", "T_wc_true"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=f"scene {i}: {name}")
    with pytest.raises(ValueError, match="backend=mujoco"):
        dataset.build_dataset(_config(tmp_path / "mjx", extra=["workers=2", "backend=mjx"]), show_progress=False)


def test_interrupted_run_leaves_no_partial_file_and_resumes(tmp_path, monkeypatch):
    cfg = _config(tmp_path)
    real = dataset.render_scene_views
    calls = []

    def flaky(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(dataset, "render_scene_views", flaky)
    with pytest.raises(KeyboardInterrupt):
        dataset.build_dataset(cfg, show_progress=False)
    out = tmp_path / "ds"
    assert sorted(p.name for p in out.iterdir()) == ["config.yaml", "scene_000.npz"]
    monkeypatch.setattr(dataset, "render_scene_views", real)
    dataset.build_dataset(cfg, show_progress=False)
    assert len(list(out.glob("scene_*.npz"))) == 2


def test_interrupted_write_leaves_no_file(tmp_path, monkeypatch):
    """The atomic write itself: a crash half-way through writing leaves neither the file nor debris."""
    cfg = _config(tmp_path, extra=["num_scenes=1"])
    real = np.savez_compressed

    def crash(file, **arrays):
        file.write(b"PK\x03\x04 half a zip")
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez_compressed", crash)
    with pytest.raises(KeyboardInterrupt):
        dataset.build_dataset(cfg, show_progress=False)
    assert sorted(p.name for p in (tmp_path / "ds").iterdir()) == ["config.yaml"]
    monkeypatch.setattr(np, "savez_compressed", real)
    dataset.build_dataset(cfg, show_progress=False)
    assert dataset.SceneViews.load(tmp_path / "ds" / "scene_000.npz").depth.shape == (6, 48, 64)


def test_damaged_scene_file_is_named_and_rendered_again(tmp_path):
    cfg = _config(tmp_path, extra=["num_scenes=1"])
    path = dataset.build_dataset(cfg, show_progress=False) / "scene_000.npz"
    good = dataset.SceneViews.load(path).depth
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(ValueError, match=r"scene_000\.npz.*not a readable"):
        dataset.SceneViews.load(path)
    with pytest.warns(UserWarning, match="rendering it again"):
        dataset.build_dataset(cfg, show_progress=False)
    np.testing.assert_array_equal(dataset.SceneViews.load(path).depth, good)


def test_a_different_config_is_refused_in_the_same_folder(tmp_path):
    dataset.build_dataset(_config(tmp_path), show_progress=False)
    with pytest.raises(ValueError, match="different config"):
        dataset.build_dataset(_config(tmp_path, extra=["seed=1"]), show_progress=False)
    # Where and how many at a time do not change the output: resuming with them changed is fine.
    dataset.build_dataset(_config(tmp_path, extra=["batch_size=3"]), show_progress=False)


def test_bad_dataset_config_names_the_key():
    with pytest.raises(ValueError, match="batch_size"):
        load_config(dataset.DatasetConfig, None, ["batch_size=0"])
    with pytest.raises(ValueError, match="num_scenes"):
        load_config(dataset.DatasetConfig, None, ["num_scenes=-1"])


def test_real_like_sensor_and_pose_noise(tmp_path):
    cfg = _config(tmp_path, "configs/real_like.yaml", ["num_scenes=1"])
    views = dataset.SceneViews.load(dataset.build_dataset(cfg, show_progress=False) / "scene_000.npz")
    assert sum(o.target for o in views.scene.objects) == 3
    assert not np.array_equal(views.T_wc, views.T_wc_true) and geometry.is_rigid(views.T_wc).all()
    offset = np.linalg.norm(views.T_wc[:, :3, 3] - views.T_wc_true[:, :3, 3], axis=1)
    assert offset.max() < 0.05
    intr = cfg.camera.intrinsics()
    model = scenes.build_model(views.scene, scenes.scene_models(views.scene), intr)
    ideal = np.asarray(make_renderer(model, intr, "mujoco").render(views.T_wc_true).depth)
    both = (ideal > 0) & (views.depth > 0)
    assert np.isfinite(views.depth).all()
    assert 0 < np.abs(views.depth[both] - ideal[both]).mean() < 0.02


def test_export_to_a_recording_reads_back_unchanged(tmp_path):
    out = dataset.build_dataset(_config(tmp_path, extra=["num_scenes=1"]), show_progress=False)
    views = dataset.SceneViews.load(out / "scene_000.npz")
    folder = dataset.export_recording(out / "scene_000.npz", tmp_path / "rec")
    rec = recording.read_recording(folder)
    np.testing.assert_array_equal(rec.depth, recording.quantise_depth(views.depth))
    np.testing.assert_array_equal(rec.T_wc, views.T_wc)
    assert rec.intrinsics == views.intrinsics and rec.table_height == views.scene.table_height
    assert scenes.Scene.from_dict(rec.scene) == views.scene


def test_cli_show_and_errors(tmp_path, capsys):
    small = [a for a in SMALL if a.startswith("camera.")]
    assert main(["show", f"out_dir={tmp_path}", "views=[0,5]", "backend=mujoco", *small]) == 0
    assert (tmp_path / "scene.png").stat().st_size > 10_000 and (tmp_path / "scene.json").is_file()
    assert main(["show", "scene.num_objects=many"]) == 2
    assert "scene.num_objects" in capsys.readouterr().err
    assert main(["show", f"out_dir={tmp_path}", "views=[100]", *small]) == 2
    assert "views" in capsys.readouterr().err
    assert main(["dataset", "--config", "configs/real_like.yaml", "--print-config"]) == 0
    assert "num_clutter: 2" in capsys.readouterr().out
