"""``jaxcls dataset``: render scenes x every viewpoint to disk (resumable)."""

from __future__ import annotations

import argparse

from jaxcls.commands import Argument, Command
from jaxcls.world.dataset import DatasetConfig


def _run(config: DatasetConfig, args: argparse.Namespace) -> str:
    from jaxcls.world.dataset import build_dataset

    return f"dataset in {build_dataset(config, overwrite=args.overwrite)}"


COMMAND = Command(
    description="Render num_scenes scenes from every hemisphere viewpoint into out_dir/scene_XXX.npz "
                "(shipped configs: synthetic, real_like). An interrupted run resumes: run the same command again.",
    resumable=True, schema=DatasetConfig, run=_run, default_config="synthetic",
    example="num_scenes=3 scene.num_objects=4",
    arguments=(Argument(("--overwrite",), {"action": "store_true", "help": "discard what out_dir holds"}),),
)
