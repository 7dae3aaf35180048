"""Files written before the layout change still load and mean the same: a dataset folder written by
revision 06eb8e1 (``tests/data/dataset_v0.1.0``: the real_like config at 64x48, 3 views, 1 scene), the
shipped weights and the run folders behind RESULTS.md."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from jaxcls.config import load_config
from jaxcls.learn.train import TrainConfig
from jaxcls.perception import pointnet
from jaxcls.world import dataset

DATA = Path(__file__).parent / "data" / "dataset_v0.1.0"
ROOT = Path(__file__).parent.parent


def test_an_old_dataset_resumes_and_renders_the_same(tmp_path):
    old = tmp_path / "old"
    shutil.copytree(DATA, old)
    config = load_config(dataset.DatasetConfig, old / "config.yaml", [f"out_dir={old}"])
    before = (old / "scene_000.npz").stat().st_mtime_ns
    dataset.build_dataset(config, show_progress=False)  # the same config: accepted, nothing to render
    assert (old / "scene_000.npz").stat().st_mtime_ns == before
    saved = dataset.SceneViews.load(old / "scene_000.npz")
    fresh_dir = dataset.build_dataset(load_config(dataset.DatasetConfig, old / "config.yaml",
                                                  [f"out_dir={tmp_path / 'new'}"]), show_progress=False)
    fresh = dataset.SceneViews.load(fresh_dir / "scene_000.npz")
    assert fresh.scene == saved.scene
    # Sensor noise (same keys) and hand-eye pose noise (now through jaxlie: float32 rounding) agree.
    np.testing.assert_allclose(fresh.depth, saved.depth, atol=1e-6)
    np.testing.assert_array_equal(fresh.object_id, saved.object_id)
    np.testing.assert_allclose(fresh.T_wc, saved.T_wc, atol=1e-6)
    np.testing.assert_array_equal(fresh.T_wc_true, saved.T_wc_true)


def test_shipped_weights_and_old_run_folders_load():
    classifier = pointnet.load_classifier()
    assert classifier.classes == ("bottle", "bowl", "box", "can", "drill", "jug", "lamp", "mug")
    runs = sorted((ROOT / "results" / "pointnet").glob("*/config.yaml"))
    assert runs, "the run folders behind RESULTS.md"
    for path in runs:
        config = load_config(TrainConfig, path)
        assert config.perception == TrainConfig().perception  # written before the block existed: defaults
        weights = path.parent / "pointnet.msgpack"
        if weights.is_file():
            assert pointnet.load_classifier(weights).classes == classifier.classes


def test_a_newer_scene_format_is_refused_with_the_file_named(tmp_path):
    from jaxcls.world import scenes

    saved = dataset.SceneViews.load(DATA / "scene_000.npz")
    data = saved.scene.to_dict() | {"version": 99}
    with pytest.raises(ValueError, match=r"x\.json: key 'version' must be 1"):
        scenes.Scene.from_dict(data, source=str(tmp_path / "x.json"))
