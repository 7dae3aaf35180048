"""Learning the classifier: labelled training clouds (``clouds``), the training loop (``train``) and its
TensorBoard log (``logs``).

Learning imports the world (to render clouds) and perception (the network, the move's settings); no
perception or world module imports it.
"""

import importlib

__all__ = ["clouds", "logs", "train"]


def __getattr__(name: str):
    if name in __all__:
        return importlib.import_module(f"jaxcls.learn.{name}")
    raise AttributeError(f"module 'jaxcls.learn' has no attribute {name!r}")
