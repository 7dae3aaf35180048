"""BOP export (``jaxcls export --format bop``, ``jaxcls.world.bop``): the layout BOP's toolkit expects, read
back to the same scenes, frames and masks, and through the project's own BOP object loader."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image
from scipy.spatial import cKDTree

from jaxcls.cli import main
from jaxcls.config import load_config
from jaxcls.world import bop, dataset
from jaxcls.world.objects import load_bop, object_set_from_config

SMALL = ["camera.width=96", "camera.height=72", "camera.fx=78.75", "camera.fy=78.75", "camera.cx=47.5",
         "camera.cy=35.5", "viewpoints.count=4", "num_scenes=2", "batch_size=4", "backend=mujoco"]


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A 2-scene real-like dataset (clutter, sensor noise, hand-eye error) and its BOP export by the CLI."""
    tmp = tmp_path_factory.mktemp("bop")
    config = load_config(dataset.DatasetConfig, "configs/real_like.yaml", [*SMALL, f"out_dir={tmp / 'ds'}"])
    folder = dataset.build_dataset(config, show_progress=False)
    assert main(["export", "--format", "bop", str(folder), str(tmp / "bop")]) == 0
    return folder, tmp / "bop"


def test_the_layout_is_bops(exported):
    _, out = exported
    assert sorted(p.name for p in out.iterdir()) == ["camera.json", "classes.json", "models", "test"]
    assert [p.name for p in bop.scene_folders(out)] == ["000000", "000001"]
    scene = out / "test" / "000001"
    camera, gt = (json.loads((scene / f"scene_{n}.json").read_text()) for n in ("camera", "gt"))
    assert list(camera) == list(gt) == ["0", "1", "2", "3"]
    assert set(camera["0"]) >= {"cam_K", "depth_scale", "cam_R_w2c", "cam_t_w2c"} and len(camera["0"]["cam_K"]) == 9
    assert set(gt["0"][0]) >= {"cam_R_m2c", "cam_t_m2c", "obj_id"} and len(gt["0"][0]["cam_R_m2c"]) == 9
    assert sorted(p.name for p in (scene / "depth").iterdir()) == [f"{v:06d}.png" for v in range(4)]
    objects = len(gt["0"])
    assert len(list((scene / "mask_visib").iterdir())) == 4 * objects
    with Image.open(scene / "depth" / "000002.png") as im:
        assert im.mode in ("I;16", "I") and im.size == (96, 72)
    info = json.loads((out / "models" / "models_info.json").read_text())
    assert sorted(info, key=int) == [str(i) for i in range(1, len(info) + 1)]
    assert {f"obj_{int(k):06d}.ply" for k in info} == {p.name for p in (out / "models").glob("*.ply")}


def test_bops_conventions_put_the_depth_on_the_models(exported):
    """Read as BOP's toolkit does (depth x depth_scale in mm, K, cam_R/t_m2c in mm): every visible pixel of an
    object, back-projected and moved into its model's frame, lies on the exported model's surface."""
    _, out = exported
    scene = out / "test" / "000000"
    camera, gt = (json.loads((scene / f"scene_{n}.json").read_text()) for n in ("camera", "gt"))
    import trimesh

    checked = 0
    for view in ("0", "3"):
        K = np.reshape(camera[view]["cam_K"], (3, 3))
        with Image.open(scene / "depth" / f"{int(view):06d}.png") as im:
            depth_mm = np.asarray(im, np.float64) * camera[view]["depth_scale"]
        for n, entry in enumerate(gt[view]):
            with Image.open(scene / "mask_visib" / f"{int(view):06d}_{n:06d}.png") as im:
                mask = (np.asarray(im) > 0) & (depth_mm > 0)
            if mask.sum() < 20:
                continue
            v, u = np.nonzero(mask)
            z = depth_mm[v, u]
            cam = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1)
            R, t = np.reshape(entry["cam_R_m2c"], (3, 3)), np.asarray(entry["cam_t_m2c"])
            model_points = (cam - t) @ R  # R^T (p - t)
            mesh = trimesh.load(out / "models" / f"obj_{entry['obj_id']:06d}.ply", force="mesh")
            surface = cKDTree(mesh.sample(20000, seed=0))
            # real-like depth noise (a few mm at 1 m): the median pixel within 5 mm of the surface
            assert np.median(surface.query(model_points)[0]) < 5.0, (view, n)
            checked += 1
    assert checked >= 4


def test_read_back_gives_the_same_scenes_frames_and_masks(exported):
    folder, out = exported
    loaded = load_bop(out)  # the project's BOP loader reads the models and classes.json
    by_name = {m.name: m for m in loaded.train + loaded.test}
    for index, scene_folder in enumerate(bop.scene_folders(out)):
        original = dataset.SceneViews.load(dataset.scene_file(folder, index))
        back = bop.read_bop_scene(scene_folder)
        a, b = original.scene, back.scene
        assert [o.class_name for o in a.objects] == [o.class_name for o in b.objects]
        assert [o.target for o in a.objects] == [o.target for o in b.objects]
        assert any(not o.target for o in a.objects)  # clutter kept as clutter
        np.testing.assert_allclose([o.position for o in b.objects], [o.position for o in a.objects], atol=1e-9)
        turn = np.subtract([o.yaw for o in b.objects], [o.yaw for o in a.objects])
        np.testing.assert_allclose(np.angle(np.exp(1j * turn)), 0.0, atol=1e-9)
        assert b.table_height == pytest.approx(a.table_height, abs=1e-9)
        np.testing.assert_allclose(back.T_wc_true, original.T_wc_true, atol=1e-9)
        np.testing.assert_allclose(back.T_wc, original.T_wc, atol=1e-9)
        assert not np.allclose(back.T_wc, back.T_wc_true)  # the reported poses are the robot's, not the truth
        assert back.intrinsics == original.intrinsics
        np.testing.assert_array_equal(back.depth == 0, original.depth == 0)
        np.testing.assert_allclose(back.depth, original.depth, atol=5.1e-5)  # 0.1 mm steps
        np.testing.assert_array_equal(back.object_id, original.object_id)
        # The instances: the same meshes (mm and back) under the loader's names and classes
        originals = {m.name: m for m in object_set_from_config(a.object_set).train
                     + object_set_from_config(a.object_set).test + object_set_from_config(a.object_set).clutter}
        for o, p in zip(a.objects, b.objects, strict=True):
            assert by_name[p.name].class_name == o.class_name
            np.testing.assert_allclose(by_name[p.name].mesh.bounds, originals[o.name].mesh.bounds, atol=1e-6)


def test_bad_input_and_overwrite(exported, tmp_path):
    folder, out = exported
    assert main(["export", "--format", "bop", str(folder), str(out)]) == 2  # exists: names --overwrite
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "keep.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="not a BOP export"):
        bop.export_bop(folder, tmp_path / "notes", overwrite=True, show_progress=False)
    assert (tmp_path / "notes" / "keep.txt").read_text() == "mine"
    with pytest.raises(FileNotFoundError, match="scene_"):
        bop.export_bop(tmp_path / "notes", tmp_path / "new", show_progress=False)
    assert not (tmp_path / "new").exists()
    copy = tmp_path / "copy"
    import shutil

    shutil.copytree(out, copy)
    (copy / "test" / "000000" / "mask_visib" / "000001_000002.png").unlink()
    with pytest.raises(bop.BopError, match=r"000001_000002\.png: missing"):
        bop.read_bop_scene(copy / "test" / "000000")
    (copy / "test" / "000001" / "scene_gt.json").write_text("{not json")
    with pytest.raises(bop.BopError, match=r"scene_gt\.json: invalid JSON"):
        bop.read_bop_scene(copy / "test" / "000001")
