"""Table 1's chosen episodes replayed and recorded for rerun's viewer (``experiments/table1.py --record``):
one row an entity a move; bad choices refused before anything runs."""

from __future__ import annotations

import dataclasses

import pytest

from jaxcls.config import load_config
from jaxcls.episode.viewer import entity_rows
from jaxcls.experiments.table1 import data, runner
from jaxcls.experiments.table1.config import Table1Config

OVERRIDES = ["runs=2", "moves=2", "timing_moves=0", "rows=[single_gr,vis_occl_hist_gr,full_gr]",
             "classifiers={shipped: ''}", "scene_source=device",
             "perception.tracking.mode=reported"]  # (the recording is the subject: half the compile time)
DATASET = ("dataset_overrides=[num_scenes=2,viewpoints.count=12,backend=mujoco,camera.width=160,camera.height=120,"
           "camera.fx=131.25,camera.fy=131.25,camera.cx=79.5,camera.cy=59.5]")


def test_a_chosen_episode_is_recorded(tmp_path):
    config = load_config(Table1Config, "table1_synthetic", [*OVERRIDES, DATASET, f"out_dir={tmp_path / 'out'}"])
    dataset, scene_set = data.open_scenes(config)
    written = runner.record_episodes(config, scene_set, dataset, ["shipped:vis_occl_hist_gr:1:1"],
                                     tmp_path / "recordings")
    assert [p.name for p in written] == ["shipped_vis_occl_hist_gr_scene0001_run1.rrd"]
    rows = entity_rows(written[0])
    assert rows["/world/camera/depth"] == config.moves and rows["/truth/objects"] == 1
    with pytest.raises(ValueError, match=r"scene must lie in 0\.\.1"):
        runner.record_episodes(config, scene_set, dataset, ["vis_occl_hist_gr:2:0"], tmp_path / "recordings")


def test_bad_choices_are_refused_naming_them():
    config = load_config(Table1Config, "table1_synthetic", [*OVERRIDES, DATASET])
    for bad, match in [("vis_occl_hist_gr:1", "expected ROW:SCENE:RUN"), ("random:0:0", "row 'random' not among"),
                       ("nobody:vis_occl_hist_gr:0:0", "classifier 'nobody'"),
                       ("full_gr:0:0", "single-view and policy"), ("vis_occl_hist_gr:0:2", r"run must lie in 0\.\.1")]:
        with pytest.raises(ValueError, match=match):
            runner.chosen_episodes(config, [bad])
    assert runner.chosen_episodes(dataclasses.replace(config), ["vis_occl_hist_gr:0:1"]) == [
        ("shipped", "vis_occl_hist_gr", 0, 1)]
