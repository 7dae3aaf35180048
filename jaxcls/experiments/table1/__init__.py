"""The paper's Table 1 and Figure 4 (``experiments/table1.py`` is its command line), one module per concern:

- ``config``: ``Table1Config`` (scenes, rows, runs, classifiers, the move's settings) and the ``out_dir`` check;
- ``data``: the dataset's config and its scenes (``Scenes``: its files, rendered first if missing, or drawn from
  its config and rendered where the episodes run, ``scene_source=device``), the stored episodes;
- ``runner``: every (classifier, row, scene, run) episode not yet stored, appended to JSONL as each batch
  finishes (the single-view and policy rows in one switched program batched over scenes and runs; PointNetFull
  and the oracle scene by scene, in passes of compiled programs on a CPU); its phases in ``run_times.json``; one
  episode timed module by module;
- ``scoring``: a row's scores after a move with its scene-bootstrap interval, the paired differences;
- ``tables``: the Markdown laid out as the paper's table, the CSV of every row x move, the module times;
- ``figure``: Figure 4, F1 over moves with 95% bands.
"""

import importlib

__all__ = ["config", "data", "figure", "runner", "scoring", "tables"]


def __getattr__(name: str):
    if name in __all__:
        return importlib.import_module(f"jaxcls.experiments.table1.{name}")
    raise AttributeError(f"module 'jaxcls.experiments.table1' has no attribute {name!r}")
