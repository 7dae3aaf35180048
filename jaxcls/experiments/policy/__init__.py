"""The learned view policy's training (``jaxcls train-policy``; the network is ``planning.learned``), one module per
concern:

- ``config``: ``PolicyConfig`` (the Table 1 config it is trained for, the training and held-out scenes, the
  DAgger rounds, the optimiser);
- ``data``: the oracle's labels (every candidate's true F1 after the move) of the states a round visits, with
  the network's input for each (``collect``: ``protocol.oracle_rollouts``'s ``tap``);
- ``train``: the listwise imitation loss, the rounds (collect, fit, evaluate on held-out scenes against the
  hand-made policy), orbax checkpoints and resumption, the weights file.
"""

import importlib

__all__ = ["config", "data", "train"]


def __getattr__(name: str):
    if name in __all__:
        return importlib.import_module(f"jaxcls.experiments.policy.{name}")
    raise AttributeError(f"module 'jaxcls.experiments.policy' has no attribute {name!r}")
