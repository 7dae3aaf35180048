"""The experiments' and benchmarks' reusable logic; the scripts in ``experiments/`` and ``benchmarks/`` are
command lines over it and import the package, never each other.

- ``table1``: the paper's Table 1 and Figure 4, by concern: ``config`` (``Table1Config``), ``data`` (the
  dataset's scenes and the stored episodes), ``runner`` (the rows' episodes, streamed to JSONL; module times),
  ``scoring`` (a row's scores and the paired differences), ``tables`` (Markdown and CSV), ``figure``
  (Figure 4);
- ``fused_views``: PointNetFull against the number of views fused, reported against true camera poses;
- ``in_scene``: PointNet on the segments of cluttered scenes (``classify_in_scene``, ``calibrate`` and
  ``classify_stability`` share its config and evaluation);
- ``segmentation``: both segmentation paths on fused scenes, scored against the posed objects;
- ``moves``: observed moves for the geometric-refinement benchmarks;
- ``peers``: the peer compositions the benchmarks time ours against (Open3D ICP for GR and for camera
  tracking, the paper's visibility count in NumPy).

The experiments import the episode and everything below it; only the commands sit above them.
"""

import importlib

__all__ = ["fused_views", "in_scene", "moves", "peers", "segmentation", "table1"]


def __getattr__(name: str):
    if name in __all__:
        return importlib.import_module(f"jaxcls.experiments.{name}")
    raise AttributeError(f"module 'jaxcls.experiments' has no attribute {name!r}")
