"""The ``jaxcls`` command: ``jaxcls <subcommand> [--config FILE] [key.sub=value ...]``."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence
from typing import Any

from jaxcls.config import ConfigError, load_config, to_yaml

_OVERRIDES_HELP = "dotted overrides applied after the config file, e.g. scene.num_objects=4 seed=3"


def _add_config_args(parser: argparse.ArgumentParser, default_config: str | None) -> None:
    parser.add_argument("--config", default=default_config,
                        help="YAML config file" + (f" (default: {default_config})" if default_config else ""))
    parser.add_argument("--print-config", action="store_true", help="print the resolved config and exit")
    parser.add_argument("overrides", nargs="*", metavar="key=value", help=_OVERRIDES_HELP)


def _configured(module: str, schema: str, run: Callable[[Any, Any, argparse.Namespace], str]
                ) -> Callable[[argparse.Namespace], None]:
    """A subcommand that loads its config (file, then overrides), prints it or runs ``run(module, config,
    args)``. The module is imported only when the subcommand runs (``train`` needs no MuJoCo)."""
    def command(args: argparse.Namespace) -> None:
        mod = importlib.import_module(f"jaxcls.{module}")
        config = load_config(getattr(mod, schema), args.config, args.overrides)
        print(to_yaml(config) if args.print_config else run(mod, config, args))
    return command


def _cmd_export(args: argparse.Namespace) -> None:
    from jaxcls.dataset import export_recording

    print(f"recording in {export_recording(args.scene_views, args.folder, overwrite=args.overwrite)}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxcls", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    show_cmd = sub.add_parser("show", help="save a PNG of a scene: depth of a few views and the view hemisphere",
                          description="Draw (or load) a scene, render a few viewpoints and save "
                                      "<out_dir>/scene.png, scene.json and config.yaml.")
    _add_config_args(show_cmd, None)
    show_cmd.set_defaults(run=_configured("viz", "ShowConfig", lambda viz, config, _: f"wrote {viz.show(config)}"))

    dataset = sub.add_parser("dataset", help="render scenes x all viewpoints to disk (resumable)",
                             description="Render num_scenes scenes from every hemisphere viewpoint into "
                                         "out_dir/scene_XXX.npz. An interrupted run resumes.")
    _add_config_args(dataset, "configs/synthetic.yaml")
    dataset.add_argument("--overwrite", action="store_true", help="discard what out_dir holds")
    dataset.set_defaults(run=_configured("dataset", "DatasetConfig", lambda dataset, config, args:
                                         f"dataset in {dataset.build_dataset(config, overwrite=args.overwrite)}"))

    train = sub.add_parser("train", help="train the PointNet classifier (resumes an interrupted run)",
                           description="Train PointNet on an object set's clouds (complete and partial views); "
                                       "writes checkpoints, metrics.json, curve.png, confusion.png and "
                                       "pointnet.msgpack into out_dir. Run again to resume.")
    _add_config_args(train, "configs/pointnet.yaml")
    train.set_defaults(run=_configured("train", "TrainConfig",
                                       lambda train, config, _: f"run in {train.train(config)}"))

    export = sub.add_parser("export", help="write one rendered scene as a recorded sequence",
                            description="Convert a dataset's scene_XXX.npz into the recorded-sequence folder "
                                        "format (16-bit PNG depth in mm, intrinsics, poses): see "
                                        "jaxcls.recording.")
    export.add_argument("scene_views", help="a scene_XXX.npz of a dataset")
    export.add_argument("folder", help="the recording folder to write")
    export.add_argument("--overwrite", action="store_true")
    export.set_defaults(run=_cmd_export)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.run(args)
    except (ConfigError, ValueError, OSError, RuntimeError) as e:  # bad input, files, missing GPU
        print(f"jaxcls {args.command}: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
