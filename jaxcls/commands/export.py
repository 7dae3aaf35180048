"""``jaxcls export``: a dataset's rendered scenes in another layout: one scene as a recorded sequence (the real
sensor's format), or every scene in the BOP benchmark's layout."""

from __future__ import annotations

import argparse
import enum

from jaxcls.commands import Argument, Command


class ExportFormat(enum.StrEnum):
    """What ``jaxcls export`` writes: ``recording`` (one scene_XXX.npz as a ``jaxcls.world.recording`` folder)
    or ``bop`` (a dataset folder, or one scene file, in BOP's layout: ``jaxcls.world.bop``)."""

    recording = "recording"
    bop = "bop"


def _run(config: None, args: argparse.Namespace) -> str:
    from jaxcls import io

    io.check_out_dir(args.folder, key="folder", whole=True)  # a file, or a place that cannot be written
    if ExportFormat(args.format) is ExportFormat.bop:
        if args.bag:
            raise ValueError("--bag: a ROS bag exports as a recording (leave out --format bop)")
        from jaxcls.world.bop import export_bop

        out = export_bop(args.source, args.folder, split=args.split, overwrite=args.overwrite)
        return f"BOP dataset in {out} (models/, camera.json, classes.json, {args.split}/NNNNNN per scene)"
    from jaxcls.world import recording, rosbag
    from jaxcls.world.dataset import export_recording

    if rosbag.is_bag(args.source):
        from jaxcls.config import load_config

        bag = rosbag.read_bag(args.source, load_config(rosbag.BagConfig, None, args.bag))
        return f"recording in {recording.write_recording(args.folder, bag, overwrite=args.overwrite)}"
    if args.bag:
        raise ValueError(f"--bag: {args.source} is not a ROS bag (a folder with metadata.yaml, or a .bag file)")
    return f"recording in {export_recording(args.source, args.folder, overwrite=args.overwrite)}"


COMMAND = Command(
    description="Convert a dataset's rendered scenes: one scene_XXX.npz (or a ROS bag: jaxcls.world.rosbag) into the "
                "recorded-sequence folder format (16-bit PNG depth in mm, intrinsics, poses: "
                "jaxcls.world.recording), or with --format bop a "
                "dataset folder (or one scene file) into the BOP benchmark's layout (jaxcls.world.bop).",
    schema=None, run=_run,
    arguments=(Argument(("source",), {"help": "a scene_XXX.npz of a dataset, or a ROS bag (--format bop: a "
                                              "dataset's folder or scene file)"}),
               Argument(("folder",), {"help": "the folder to write"}),
               Argument(("--format",), {"choices": [f.value for f in ExportFormat], "default": "recording",
                                        "help": "recording (default) or bop"}),
               Argument(("--split",), {"default": "test", "help": "--format bop: the split folder's name"}),
               Argument(("--bag",), {"nargs": "*", "default": [], "metavar": "KEY=VALUE",
                                     "help": "a ROS bag's topics and frames (jaxcls.world.rosbag.BagConfig), e.g. "
                                             "depth_topic=/depth world_frame=map"}),
               Argument(("--overwrite",), {"action": "store_true",
                                           "help": "replace an earlier export of the same format"})),
)
