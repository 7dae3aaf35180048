"""``jaxcls train``: train the PointNet classifier (resumes an interrupted run). Needs no MuJoCo once the
training clouds are cached."""

from __future__ import annotations

import argparse

from jaxcls.commands import Command
from jaxcls.learn.train import TrainConfig


def _run(config: TrainConfig, args: argparse.Namespace) -> str:
    from jaxcls import io
    from jaxcls.learn.train import train

    io.check_out_dir(config.out_dir)  # before the clouds are made: a file, or a folder that cannot be written
    run = train(config)
    return (f"run in {run}; the weights are {run / 'pointnet.msgpack'} and {run / 'pointnet.json'} beside it "
            "(classes, model settings, temperature): keep the two together, pass the .msgpack as classifier=..."
            + (f"; curves: tensorboard --logdir {run / 'tensorboard'}" if config.tensorboard else ""))


COMMAND = Command(
    description="Train PointNet on an object set's clouds (complete and partial views); writes checkpoints, "
                "metrics.json, curve.png, confusion.png, TensorBoard event files (tensorboard/), pointnet.msgpack and "
                "pointnet.json into out_dir "
                "(shipped configs: pointnet, pointnet_folder). Run the same command again to resume.",
    resumable=True, schema=TrainConfig, run=_run, default_config="pointnet", example="epochs=10 batch_size=64",
)
