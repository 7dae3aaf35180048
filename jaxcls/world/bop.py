"""A dataset's scenes in the layout of the BOP benchmark (bop.felk.cvut.cz), which every pose-estimation and
recognition toolkit reads, and back.

``export_bop(dataset, out)`` writes (units as BOP: millimetres; rotations row-major 3x3)::

    out/
        camera.json                 the sensor: width, height, fx, fy, cx, cy, depth_scale
        models/obj_000001.ply ...   every instance of the dataset's object set (mm, the project's model frame)
        models/models_info.json     min_x/y/z, size_x/y/z, diameter per object id (``objects.models_info``)
        classes.json                object id -> class (the project's BOP loader reads it)
        <split>/000000/             one folder a scene (the dataset's scene index)
            scene_camera.json       per view: cam_K, depth_scale, cam_R_w2c / cam_t_w2c (the pose the frame was
                                    rendered from); jaxcls_R_w2c / jaxcls_t_w2c: the pose the robot reported
                                    (hand-eye error on the real-like set)
            scene_gt.json           per view: per object, cam_R_m2c, cam_t_m2c, obj_id (jaxcls_target: whether the
                                    object is scored; clutter is not)
            depth/000000.png        uint16, depth [mm] = value x depth_scale (0.1: tenths of a millimetre)
            mask_visib/000000_000001.png   per view and object (scene_gt's order): its visible pixels (255)

BOP's extra keys (``jaxcls_*``) are ignored by its toolkit. The object ids number the set's instances in name
order from 1; the views keep the dataset's viewpoint order. ``read_bop_scene`` reads a scene folder back as
``SceneViews`` whose object set is the exported folder (instances named ``obj_000001`` as ``load_bop`` names
them): the same poses, classes, target flags, depth (to 0.05 mm) and object masks.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from tqdm.auto import tqdm

from jaxcls import geometry, io
from jaxcls.world import recording, scenes
from jaxcls.world.dataset import SceneViews
from jaxcls.world.objects import ObjectSetConfig, models_info, object_set_from_config

DEPTH_SCALE_MM = 0.1  # BOP's depth_scale: depth [mm] = PNG value x this (recording's units: 10,000 a metre)
_UNITS_PER_METRE = 1000.0 / DEPTH_SCALE_MM


class BopError(ValueError):
    """A BOP folder that cannot be read as this project wrote it: names the file and key."""


def _scene_files(dataset: Path) -> list[Path]:
    if dataset.is_file():
        return [dataset]
    files = sorted(dataset.glob("scene_*.npz"))
    if not files:
        raise FileNotFoundError(f"export_bop: {dataset} holds no scene_*.npz (a folder written by jaxcls dataset)")
    return files


def _object_ids(object_set_config: ObjectSetConfig) -> tuple[Any, dict[str, int]]:
    object_set = object_set_from_config(object_set_config)
    models = sorted(object_set.train + object_set.test + object_set.clutter, key=lambda m: m.name)
    return models, {m.name: i + 1 for i, m in enumerate(models)}


def _rt(T: np.ndarray) -> dict[str, list[float]]:
    """A rigid transform in metres as BOP's rotation (row-major) and translation in mm."""
    return {"R": [float(v) for v in T[:3, :3].reshape(-1)], "t": [float(v) * 1000.0 for v in T[:3, 3]]}


def export_bop(dataset: str | Path, out: str | Path, split: str = "test", overwrite: bool = False,
               show_progress: bool = True) -> Path:
    """Write the scenes of ``dataset`` (a folder written by ``jaxcls dataset``, or one ``scene_XXX.npz``) to
    ``out`` in BOP's layout (module docstring), as a whole: ``out`` appears complete or not at all.
    ``overwrite`` replaces an earlier export (a folder holding ``camera.json`` and ``models/``, or an empty
    one), never anything else. Returns ``out``."""
    dataset, out = Path(dataset), Path(out)
    files = _scene_files(dataset)
    if out.exists() or out.is_symlink():
        if not overwrite:
            raise FileExistsError(f"export_bop: {out} already exists (overwrite=True, or --overwrite, replaces it)")
        if not out.is_dir() or (any(out.iterdir()) and not ((out / "camera.json").is_file()
                                                           and (out / "models").is_dir())):
            raise FileExistsError(f"export_bop: {out} exists and is not a BOP export; refusing to overwrite")
    first = SceneViews.load(files[0])
    models, ids = _object_ids(first.scene.object_set)
    k = first.intrinsics
    with io.atomic_folder(out) as tmp:
        (tmp / "models").mkdir()
        info = {}
        for model in models:
            mesh = model.mesh.copy()
            mesh.apply_scale(1000.0)
            mesh.export(tmp / "models" / f"obj_{ids[model.name]:06d}.ply")
            info[str(ids[model.name])] = models_info(mesh.vertices)
        io.write_json(tmp / "models" / "models_info.json", info)
        io.write_json(tmp / "classes.json", {str(ids[m.name]): m.class_name for m in models})
        io.write_json(tmp / "camera.json", {"width": k.width, "height": k.height, "fx": k.fx, "fy": k.fy,
                                            "cx": k.cx, "cy": k.cy, "depth_scale": DEPTH_SCALE_MM})
        for file in tqdm(files, desc="BOP export", unit="scene", disable=not show_progress):
            views = first if file == files[0] else SceneViews.load(file)
            if views.scene.object_set != first.scene.object_set or views.intrinsics != k:
                raise ValueError(f"export_bop: {file} has another object set or camera than {files[0]}")
            index = int(file.stem.split("_")[-1]) if file.stem.startswith("scene_") else 0
            _write_scene(tmp / split / f"{index:06d}", views, ids)
    return out


def _write_scene(folder: Path, views: SceneViews, ids: dict[str, int]) -> None:
    (folder / "depth").mkdir(parents=True)
    (folder / "mask_visib").mkdir()
    k = views.intrinsics
    K = [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0]
    T_wm = views.scene.object_poses()
    camera, gt = {}, {}
    raw = recording.depth_to_raw(views.depth, _UNITS_PER_METRE)
    for v in range(views.depth.shape[0]):
        T_cw = np.linalg.inv(views.T_wc_true[v])
        true, told = _rt(T_cw), _rt(np.linalg.inv(views.T_wc[v]))
        camera[str(v)] = {"cam_K": K, "depth_scale": DEPTH_SCALE_MM, "cam_R_w2c": true["R"], "cam_t_w2c": true["t"],
                          "jaxcls_R_w2c": told["R"], "jaxcls_t_w2c": told["t"]}
        gt[str(v)] = []
        for n, placed in enumerate(views.scene.objects):
            pose = _rt(T_cw @ T_wm[n])
            gt[str(v)].append({"cam_R_m2c": pose["R"], "cam_t_m2c": pose["t"], "obj_id": ids[placed.name],
                               "jaxcls_target": bool(placed.target)})
            mask = np.where(views.object_id[v] == n, 255, 0).astype(np.uint8)
            Image.fromarray(mask).save(folder / "mask_visib" / f"{v:06d}_{n:06d}.png")
        recording._write_png16(folder / "depth" / f"{v:06d}.png", raw[v])
    io.write_json(folder / "scene_camera.json", camera)
    io.write_json(folder / "scene_gt.json", gt)


def _json(path: Path) -> dict:
    return io.read_json_object(path, BopError)


def _matrix(path: Path, entry: dict, key: str, R: str, t: str) -> np.ndarray:
    try:
        T = np.eye(4)
        T[:3, :3] = np.asarray(entry[R], np.float64).reshape(3, 3)
        T[:3, 3] = np.asarray(entry[t], np.float64).reshape(3) / 1000.0
    except (KeyError, TypeError, ValueError) as e:
        raise BopError(f"{path}: key {key!r}: no 3x3 {R} and 3-vector {t} ({type(e).__name__}: {e})") from None
    return T


def read_bop_scene(scene_folder: str | Path) -> SceneViews:
    """A scene folder of a BOP export (``<out>/<split>/NNNNNN``) as ``SceneViews``: its object set is the
    export (``ObjectSetConfig(source=<out>)``, instances ``obj_NNNNNN``), depth in metres, object ids from the
    visible masks, T_wc_true from ``cam_*_w2c`` and T_wc from ``jaxcls_*_w2c`` (the true pose where absent).
    Each object is placed back on the table by its pose in the first view. BopError names a missing or
    malformed file and key."""
    folder = Path(scene_folder)
    root = folder.parent.parent
    camera_file, gt_file = folder / "scene_camera.json", folder / "scene_gt.json"
    camera, gt = _json(camera_file), _json(gt_file)
    sensor = _json(root / "camera.json")
    classes = {int(key): name for key, name in _json(root / "classes.json").items()}
    try:
        intrinsics = geometry.Intrinsics(width=int(sensor["width"]), height=int(sensor["height"]),
                                         fx=float(sensor["fx"]), fy=float(sensor["fy"]), cx=float(sensor["cx"]),
                                         cy=float(sensor["cy"]))
    except (KeyError, TypeError, ValueError) as e:
        raise BopError(f"{root / 'camera.json'}: no width, height, fx, fy, cx, cy ({type(e).__name__}: {e})") from None
    views = sorted(camera, key=int)
    if sorted(gt, key=int) != views:
        raise BopError(f"{gt_file}: its views {sorted(gt, key=int)} differ from {camera_file}'s {views}")
    V, H, W = len(views), intrinsics.height, intrinsics.width
    depth = np.zeros((V, H, W), np.float32)
    object_id = np.full((V, H, W), -1, np.int32)
    T_true, T_told = np.zeros((V, 4, 4)), np.zeros((V, 4, 4))
    placed: list[scenes.PlacedObject] = []
    table_height = 0.0
    for i, key in enumerate(views):
        T_cw = _matrix(camera_file, camera[key], key, "cam_R_w2c", "cam_t_w2c")
        T_true[i] = np.linalg.inv(T_cw)
        told = camera[key]
        T_told[i] = (np.linalg.inv(_matrix(camera_file, told, key, "jaxcls_R_w2c", "jaxcls_t_w2c"))
                     if "jaxcls_R_w2c" in told else T_true[i])
        scale = float(told.get("depth_scale", sensor.get("depth_scale", 1.0)))
        depth[i] = recording.raw_to_depth(recording._read_png16(folder / "depth" / f"{int(key):06d}.png",
                                                                intrinsics), 1000.0 / scale)
        for n, entry in enumerate(gt[key]):
            mask_file = folder / "mask_visib" / f"{int(key):06d}_{n:06d}.png"
            if not mask_file.is_file():
                raise BopError(f"{mask_file}: missing (scene_gt.json view {key!r} lists object {n})")
            with Image.open(mask_file) as im:
                object_id[i][np.asarray(im) > 0] = n
            if i == 0:
                T_wm = T_true[i] @ _matrix(gt_file, entry, key, "cam_R_m2c", "cam_t_m2c")
                obj = int(entry.get("obj_id", -1))
                if obj not in classes:
                    raise BopError(f"{gt_file}: view {key!r} object {n}: obj_id {obj} is not in classes.json")
                placed.append(scenes.PlacedObject(name=f"obj_{obj:06d}", class_name=classes[obj],
                                                  position=(float(T_wm[0, 3]), float(T_wm[1, 3])),
                                                  yaw=math.atan2(T_wm[1, 0], T_wm[0, 0]),
                                                  target=bool(entry.get("jaxcls_target", True))))
                table_height = float(T_wm[2, 3])
    scene = scenes.Scene(objects=tuple(placed), object_set=ObjectSetConfig(source=str(root)),
                         table_height=table_height)
    return SceneViews(scene=scene, intrinsics=intrinsics, depth=depth, object_id=object_id, T_wc=T_told,
                      T_wc_true=T_true, backend="bop")


def scene_folders(out: str | Path, split: str = "test") -> Iterable[Path]:
    """The scene folders of a BOP export's ``split``, in order."""
    return sorted(p for p in (Path(out) / split).iterdir() if p.is_dir())


__all__ = ["DEPTH_SCALE_MM", "BopError", "export_bop", "read_bop_scene", "scene_folders"]
