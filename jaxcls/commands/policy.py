"""``jaxcls train-policy``: train the learned view policy by imitation of the oracle (resumes an interrupted run)."""

from __future__ import annotations

import argparse

from jaxcls.commands import Command
from jaxcls.experiments.policy.config import PolicyConfig


def _run(config: PolicyConfig, args: argparse.Namespace) -> str:
    from jaxcls import io
    from jaxcls.experiments.policy.train import train

    io.check_out_dir(config.out_dir)
    run = train(config)
    return (f"run in {run}; the weights are {run / 'policy.msgpack'} and {run / 'policy.json'} beside it: pass the "
            f".msgpack as nbv.learned.weights=... with episode.policy=learned (jaxcls run) or the learned_gr row "
            f"(experiments/table1.py); the rounds' figures: {run / 'metrics.json'}, {run / 'curve.png'}")


COMMAND = Command(
    description="Train the learned view policy for a Table 1 config by imitation of the oracle (DAgger rounds: the "
                "oracle labels every candidate of the states the rounds visit with its true F1; the network is "
                "fitted, then evaluated on held-out scenes against VisOcclHistGR); writes decisions_<r>.npz, "
                "checkpoints, metrics.json, curve.png, policy.msgpack and policy.json into out_dir (shipped "
                "configs: policy_real_like, policy_synthetic). Run the same command again to resume.",
    resumable=True, schema=PolicyConfig, run=_run, default_config="policy_real_like", example="rounds=4 epochs=50",
)
