"""Figures of scenes and depth frames (matplotlib, headless)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import numpy as np
from matplotlib.figure import Figure

from jaxcls import geometry, scenes
from jaxcls.assets import ObjectSetConfig, object_set_from_config
from jaxcls.config import save_config
from jaxcls.render import make_renderer, resolve_backend


@dataclasses.dataclass(frozen=True)
class ShowConfig:
    """``jaxcls show``: one scene, a few of its views, and the viewpoint hemisphere."""

    out_dir: str = "runs/show"
    seed: int = 0
    scene_file: str = ""  # a scene JSON to show instead of drawing one
    views: tuple[int, ...] = (0, 33, 66, 99)
    backend: Literal["auto", "mujoco", "mjx", "warp"] = "auto"
    objects: ObjectSetConfig = dataclasses.field(default_factory=ObjectSetConfig)
    scene: scenes.SceneConfig = dataclasses.field(default_factory=scenes.SceneConfig)
    camera: geometry.CameraConfig = dataclasses.field(default_factory=geometry.CameraConfig)
    viewpoints: geometry.ViewpointConfig = dataclasses.field(default_factory=geometry.ViewpointConfig)


def show(config: ShowConfig) -> Path:
    """Render the scene and save ``scene.png`` (depth, object ids, hemisphere), ``scene.json`` and the config."""
    out = Path(config.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if config.scene_file:
        scene = scenes.Scene.load(config.scene_file)
        object_set = object_set_from_config(scene.object_set)
    else:
        object_set = object_set_from_config(config.objects)
        scene = scenes.sample_scene(object_set, config.scene, config.seed, config.objects)
    models = scenes.scene_models(scene, object_set)
    intrinsics = config.camera.intrinsics()
    T_wc = scenes.viewpoints(scene, models, config.viewpoints)
    bad = [v for v in config.views if not 0 <= v < len(T_wc)]
    if bad:
        raise ValueError(f"show: views {bad} are outside 0..{len(T_wc) - 1}")
    backend = resolve_backend(config.backend)
    renderer = make_renderer(scenes.build_model(scene, models, intrinsics), intrinsics, backend)
    frames = renderer.render(T_wc[list(config.views)])
    figure = plot_scene(scene, T_wc, config.views, np.asarray(frames.depth), np.asarray(frames.object_id))
    path = out / "scene.png"
    figure.savefig(path, dpi=80)
    scene.save(out / "scene.json")
    save_config(config, out / "config.yaml")
    return path


def plot_scene(scene: scenes.Scene, T_wc: np.ndarray, views, depth: np.ndarray,
               object_id: np.ndarray) -> Figure:
    """Depth and object ids of ``views`` (rows of ``depth: [K, H, W]``) beside the view hemisphere."""
    k = len(views)
    figure = Figure(figsize=(3.2 * k + 5, 5.5))  # no pyplot: no global state, no GUI backend
    grid = figure.add_gridspec(2, k + 2)
    for col, view in enumerate(views):
        ax = figure.add_subplot(grid[0, col])
        valid = depth[col] > 0
        shown = np.where(valid, depth[col], np.nan)
        image = ax.imshow(shown, cmap="viridis")
        ax.set_title(f"view {view}: depth (m)", fontsize=9)
        ax.axis("off")
        figure.colorbar(image, ax=ax, fraction=0.035)
        ax = figure.add_subplot(grid[1, col])
        ax.imshow(np.ma.masked_less(object_id[col], 0), cmap="tab10", vmin=0, vmax=9, interpolation="nearest")
        ax.set_title(f"view {view}: object ids", fontsize=9)
        ax.axis("off")
    ax = figure.add_subplot(grid[:, k:], projection="3d")
    eyes = T_wc[:, :3, 3]
    ax.scatter(*eyes.T, s=8, c="tab:blue", label="viewpoints")
    ax.scatter(*eyes[list(views)].T, s=40, c="tab:red", label="shown")
    for obj in scene.objects:
        ax.scatter(obj.position[0], obj.position[1], scene.table_height, s=30,
                   c="k" if obj.target else "tab:gray")
        ax.text(obj.position[0], obj.position[1], scene.table_height + 0.05, obj.class_name, fontsize=7)
    ax.set_box_aspect((1, 1, 0.5))
    ax.set_title(f"{len(T_wc)} viewpoints, {scene.num_objects} objects", fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    figure.tight_layout()
    return figure

