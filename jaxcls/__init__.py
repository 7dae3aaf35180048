"""jaxcls: active 3D classification of multiple objects in cluttered scenes, in pure-functional JAX.

The folders follow the pipeline (``docs/ARCHITECTURE.md``):

- ``world``: object sets, cluttered scenes, depth rendering and the sensor model, datasets, recordings,
  and ``world.setup.make_world``, the one world set-up;
- ``perception``: one move's perception, stage by stage (``foreground``, ``tsdf``, ``segment``,
  ``pointnet``), composed by ``perception.observe``;
- ``learn``: training clouds and the classifier's training;
- at the top: ``geometry`` (cameras, poses as ``jaxlie.SE3``, viewpoints), ``math`` (NaN-safe norms and
  divisions), ``config`` (YAML -> typed configs), ``io`` (atomic writes), ``allocator`` (freed memory kept
  for reuse), ``precision`` (full float32 products on GPUs), ``viz`` (figures), ``report`` (Markdown
  tables) and ``cli`` with ``commands`` (the ``jaxcls`` command).

Imports run one way: world -> perception -> (planning -> episode) -> commands; learning reads the world
and perception. Subpackages load on first use, so that training a classifier does not need MuJoCo.

Importing ``jaxcls`` sets XLA:CPU flags that give each compiled program fewer memory maps and installs a
guard that frees compiled programs before the process reaches the kernel's memory-map limit
(``xla_flags``: a long process, such as the whole test suite or a notebook, otherwise dies in XLA). Import
it before running anything with JAX; ``JAXCLS_XLA_FLAGS=off`` leaves ``$XLA_FLAGS`` as it is.
"""

import importlib

from jaxcls import xla_flags as _xla_flags

_xla_flags.apply()  # before JAX starts its CPU backend, when XLA reads $XLA_FLAGS (once per process)

__version__ = "0.2.0"

__all__ = ["commands", "config", "geometry", "io", "learn", "math", "perception", "precision", "report", "viz", "world"]


def __getattr__(name: str):
    if name in __all__:
        return importlib.import_module(f"jaxcls.{name}")
    raise AttributeError(f"module 'jaxcls' has no attribute {name!r}")
