"""``jaxcls show``: draw (or load) a scene, render a few viewpoints, save a figure, the scene and the config."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from jaxcls.commands import Argument, Command
from jaxcls.config import bounded, check_bounds
from jaxcls.world.dataset import DatasetConfig
from jaxcls.world.setup import WorldConfig


@dataclasses.dataclass(frozen=True)
class ShowConfig(WorldConfig):
    """``jaxcls show``: one scene, a few of its views (through the sensor model), the viewpoint hemisphere."""

    out_dir: str = "runs/show"
    seed: int = bounded(0, ge=0, lt=2**32)  # the scene drawn and the sensor's noise (a 32-bit unsigned integer)
    scene_file: str = ""  # a scene JSON to show instead of drawing one (seed, scene.*, objects.* then unused)
    views: tuple[int, ...] = (0, 33, 66, 99)

    def __post_init__(self) -> None:
        check_bounds(self)


def _check_scene_file_alone(config: ShowConfig, overrides: list[str]) -> None:
    """With ``scene_file``, the settings that draw a scene would be ignored: refuse them when given on the
    command line, naming each (a config file's values are the file's business: a dataset config's scene)."""
    unused = sorted({o.split("=", 1)[0] for o in overrides
                     if o.split("=", 1)[0] == "seed" or o.startswith(("scene.", "objects."))})
    if unused:
        raise ValueError(f"show: scene_file={config.scene_file} gives the scene, so {', '.join(unused)} would be "
                         "ignored; drop those settings or the scene file")


def free_folder(out_dir: str | Path, overwrite: bool) -> Path:
    """``out_dir`` (created), or with ``overwrite`` off and ``out_dir`` not empty, the first of
    ``out_dir-2``, ``out_dir-3``, ... that can be created empty (a new run never replaces an old one unless
    asked; a file of that name is skipped; creation is exclusive, so two runs never share one). An
    ``out_dir`` that is a file, or that cannot be written, is refused (``io.check_out_dir``)."""
    from jaxcls import io

    out = io.check_out_dir(out_dir, whole=not overwrite)
    if overwrite or not out.exists() or (out.is_dir() and not any(out.iterdir())):
        out.mkdir(parents=True, exist_ok=True)
        return out
    k = 2
    while True:
        candidate = out.with_name(f"{out.name}-{k}")
        try:
            candidate.mkdir(parents=True)
            return candidate
        except FileExistsError:
            if candidate.is_dir() and not any(candidate.iterdir()):
                return candidate
            k += 1


def show(config: ShowConfig, overwrite: bool = False, overrides: list[str] | tuple[str, ...] = ()) -> Path:
    """Render the scene and save ``scene.png`` (depth after the sensor model, object ids, hemisphere),
    ``scene.json`` and ``config.yaml`` in ``out_dir`` (or a numbered sibling, see ``free_folder``).
    ``overrides``: the command line's, checked against ``scene_file``."""
    import jax
    import numpy as np

    from jaxcls import io, viz
    from jaxcls.config import save_config
    from jaxcls.world import scenes
    from jaxcls.world.setup import make_world

    io.check_out_dir(config.out_dir)  # before any work: a bad out_dir costs no scene and no render
    scene = None
    if config.scene_file:
        _check_scene_file_alone(config, list(overrides))
        scene = scenes.Scene.load(config.scene_file)
        config = dataclasses.replace(config, objects=scene.object_set)
    world = make_world(config.world_config(), config.seed, scene=scene)
    config = dataclasses.replace(config, scene=world.config.scene)  # what was shown, for config.yaml
    out = free_folder(config.out_dir, overwrite)  # before rendering: a bad out_dir costs no render
    views = list(config.views)
    depth, _, object_id, _ = world.measure(jax.random.key(config.seed), views)
    figure = viz.plot_scene(world.scene, world.viewpoints, views, np.asarray(depth), np.asarray(object_id),
                            noisy=config.sensor != WorldConfig().sensor)
    viz.save(figure, out / "scene.png")
    world.scene.save(out / "scene.json")
    save_config(config, out / "config.yaml")
    return out / "scene.png"


def _run(config: ShowConfig, args: argparse.Namespace) -> str:
    path = show(config, overwrite=args.overwrite, overrides=args.overrides)
    if path.parent != Path(config.out_dir).resolve():
        return (f"wrote {path} (out_dir {config.out_dir} is not empty: a new run goes beside it; --overwrite "
                "writes into it)")
    return f"wrote {path}"


COMMAND = Command(
    description="Draw (or load) a scene, render a few viewpoints (through the sensor model: a dataset config "
                "such as real_like previews its noisy depth) and save <out_dir>/scene.png, scene.json and "
                "config.yaml. An existing out_dir is kept: the run goes to out_dir-2, -3, ... unless --overwrite.",
    schema=ShowConfig, run=_run, example="seed=3 scene.num_objects=6 views=[0,50]",
    arguments=(Argument(("--overwrite",), {"action": "store_true", "help": "write into out_dir even if not empty"}),),
    reads_world_of=(DatasetConfig,), world_schema=WorldConfig,
)
