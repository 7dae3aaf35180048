"""``jaxcls export``: one rendered scene of a dataset as a recorded sequence (the real sensor's format)."""

from __future__ import annotations

import argparse

from jaxcls.commands import Argument, Command


def _run(config: None, args: argparse.Namespace) -> str:
    from jaxcls import io
    from jaxcls.world.dataset import export_recording

    io.check_out_dir(args.folder, key="folder", whole=True)  # a file, or a place that cannot be written
    return f"recording in {export_recording(args.scene_views, args.folder, overwrite=args.overwrite)}"


COMMAND = Command(
    description="Convert a dataset's scene_XXX.npz into the recorded-sequence folder format (16-bit PNG depth "
                "in mm, intrinsics, poses): see jaxcls.world.recording.",
    schema=None, run=_run,
    arguments=(Argument(("scene_views",), {"help": "a scene_XXX.npz of a dataset"}),
               Argument(("folder",), {"help": "the recording folder to write"}),
               Argument(("--overwrite",), {"action": "store_true", "help": "replace an existing recording"})),
)
