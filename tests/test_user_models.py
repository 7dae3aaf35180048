"""The user's own models end to end (issue 23, item 2): ``jaxcls dataset`` -> ``jaxcls train`` (tiny) ->
``experiments/table1.py`` (tiny) with the trained classifier, the README's path. On a BOP folder with one
model per class (as LINEMOD has; trained and evaluated on held-out views and poses of the same models) and
on class folders with two models per class (evaluated on the held-out one, which the scenes show; and run in
Table 1)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from jaxcls import io
from jaxcls.cli import main as cli_main

ROOT = Path(__file__).parent.parent


def _write_bop(root: Path) -> None:
    """Three objects in mm, one per class, centred on their origin as BOP models are."""
    models = root / "models"
    models.mkdir(parents=True)
    meshes = {1: trimesh.creation.box(extents=[50.0, 70.0, 90.0]),
              2: trimesh.creation.cylinder(radius=35.0, height=120.0, sections=24),
              3: trimesh.creation.icosphere(radius=45.0, subdivisions=2)}
    info = {}
    for obj_id, mesh in meshes.items():
        mesh.export(models / f"obj_{obj_id:06d}.ply")
        lo, size = mesh.bounds[0], np.ptp(mesh.vertices, axis=0)
        diameter = float(np.max(np.linalg.norm(mesh.vertices[:, None] - mesh.vertices[None], axis=-1)))
        info[str(obj_id)] = {"diameter": diameter, "min_x": lo[0], "min_y": lo[1], "min_z": lo[2],
                             "size_x": size[0], "size_y": size[1], "size_z": size[2]}
    (models / "models_info.json").write_text(json.dumps(info))
    (root / "classes.json").write_text(json.dumps({"1": "box", "2": "can", "3": "ball"}))


def _write_folders(root: Path) -> None:
    """Three classes in metres, two instances each (``root/<class>/<instance>.ply``)."""
    shapes = {"box": lambda s: trimesh.creation.box(extents=[0.05 * s, 0.07, 0.09 * s]),
              "can": lambda s: trimesh.creation.cylinder(radius=0.035 * s, height=0.12, sections=24),
              "ball": lambda s: trimesh.creation.icosphere(radius=0.045 * s, subdivisions=2)}
    for name, make in shapes.items():
        (root / name).mkdir(parents=True)
        for i, s in enumerate((1.0, 0.8)):
            make(s).export(root / name / f"{name}{i}.ply")


# The scenes at half the Kinect's resolution (Table 1's small tests do the same): a quarter of the pixels to
# render, fuse and segment.
HALF_KINECT = ["camera.width=320", "camera.height=240", "camera.fx=262.5", "camera.fy=262.5", "camera.cx=159.5",
               "camera.cy=119.5"]

LAYOUTS = {  # layout: (writer, objects overrides, scene split, what training is evaluated on)
    "bop": (_write_bop, [], "all", "held-out views and poses of the training instances"),
    "folders": (_write_folders, ["objects.test_fraction=0.5"], "test", "held-out instances"),
}


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_own_models_dataset_train_table1(tmp_path, layout):
    write, extra, split, evaluated_on = LAYOUTS[layout]
    source = tmp_path / layout
    write(source)
    objects = [f"objects.source={source}", "objects.surface_samples=600", *extra]
    data = tmp_path / "data"
    assert cli_main(["dataset", "--config", "synthetic", *objects, f"out_dir={data}", "num_scenes=2",
                     "scene.num_objects=3", f"scene.split={split}", "viewpoints.count=10", "backend=mujoco",
                     *HALF_KINECT]) == 0
    run = tmp_path / "run"
    small = [f"out_dir={run}", f"data.cache_dir={tmp_path / 'cache'}", "epochs=1", "steps_per_epoch=2",
             "batch_size=8", "model.num_points=64", "eval_batch=16", "eval_rotations=2", "data.full_points=600",
             "data.views_per_instance=1", "data.occluded_per_instance=0", "data.fused_per_instance=0",
             "data.image_scale=0.25", "mix.occluded=0", "mix.fused=0", "data.scenes=1", "data.scene_max_views=2"]
    assert cli_main(["train", "--config", "pointnet_folder", *objects, *small]) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["classes"] == ["ball", "box", "can"]
    assert metrics["evaluated_on"] == evaluated_on
    assert metrics["final"]["full"]["count"] == 3 * 2  # each class's one (held-out) model, 2 yaws
    # The recipe that works in the loop: segments of cluttered scenes of the models, and the yaw head.
    assert metrics["final"]["scene"]["count"] > 0 and "yaw_error_deg" in metrics["final"]["full"]
    info = json.loads((run / "pointnet.json").read_text())
    assert info["classes"] == ["ball", "box", "can"] and len(info["yaw_orders"]) == 3

    if layout != "folders":
        return  # (Table 1 once: it reads the models through the dataset's config, the loader checked above)
    spec = importlib.util.spec_from_file_location(f"table1_{layout}", ROOT / "experiments" / "table1.py")
    table1 = importlib.util.module_from_spec(spec)
    sys.modules[f"table1_{layout}"] = table1
    spec.loader.exec_module(table1)
    out = tmp_path / "table"
    config = tmp_path / "table1.yaml"
    config.write_text(f"out_dir: {out}\ndataset: {data}\nruns: 2\nmoves: 2\ntiming_moves: 0\nresamples: 100\n"
                      f"rows: [vis_occl_hist_gr]\nclassifiers: {{mine: {run / 'pointnet.msgpack'}}}\n"
                      "refine: {yaw_source: hypotheses}\n")
    table1.main(["--config", str(config)])
    records = io.read_jsonl(out / "episodes.jsonl")
    assert len(records) == 2 * 2  # 2 scenes x 2 runs
    assert all(len(r["true"]) == 3 and set(r["true"]) == {0, 1, 2} for r in records)
    assert "VisOcclHistGR" in (out / "table.md").read_text()


def test_clutter_from_a_separate_set_stands_on_the_table_and_is_never_scored(tmp_path):
    """``objects.clutter_source``: the clutter of a scene comes from another set (the builtin shapes here),
    never from the user's classes; the scene's JSON names it, so the scene reloads; clutter has no label."""
    from jaxcls.episode.scoring import Truth
    from jaxcls.geometry import CameraConfig, ViewpointConfig
    from jaxcls.world.objects import ObjectSetConfig, object_set_from_config
    from jaxcls.world.scenes import Scene, SceneConfig, scene_models
    from jaxcls.world.setup import WorldConfig, make_world

    _write_folders(tmp_path / "mine")
    objects = ObjectSetConfig(source=str(tmp_path / "mine"), test_fraction=0.5, surface_samples=300,
                              clutter_source="builtin")
    object_set = object_set_from_config(objects)
    assert object_set.classes == ("ball", "box", "can")
    assert object_set.clutter and all(m.name.startswith("clutter:") for m in object_set.clutter)
    config = WorldConfig(objects=objects, scene=SceneConfig(num_objects=4, num_clutter=2, split="all"),
                         camera=CameraConfig.kinect_v1(0.25), viewpoints=ViewpointConfig(count=12), backend="mujoco")
    for seed in range(3):
        world = make_world(config, seed, object_set=object_set)
        clutter = [o for o in world.scene.objects if not o.target]
        targets = [o for o in world.scene.objects if o.target]
        assert len(clutter) == 2 and all(o.name.startswith("clutter:") for o in clutter)
        assert len(targets) == 2 and all(o.class_name in object_set.classes for o in targets)
        assert all(o.class_name not in object_set.classes for o in clutter)  # builtin classes: none of the user's
        truth = Truth.from_scene(world.scene, object_set)
        assert [int(x) for x in truth.label[~truth.target]] == [-1, -1]
        assert (truth.label[truth.target] >= 0).all()
        # The scene's JSON names the clutter set: loaded alone, it finds every model again.
        again = Scene.from_dict(world.scene.to_dict())
        assert [m.name for m in scene_models(again)] == [o.name for o in world.scene.objects]
        # Every object is drawn: each one's id appears in some of the views.
        seen = np.unique(np.asarray(world.render(np.arange(12)).object_id))
        assert set(range(4)) <= set(seen.tolist())

    with pytest.raises(ValueError, match=r"objects\.clutter_source"):
        object_set_from_config(ObjectSetConfig(source=str(tmp_path / "mine"), test_fraction=0.5,
                                               clutter_source=str(tmp_path / "nowhere")))
