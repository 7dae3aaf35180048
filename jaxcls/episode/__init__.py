"""The active episode (paper Sec. 3-4): T moves of perceive -> refine -> choose the next view.

- ``active``: the functional environment: ``Episode`` (static settings, weights, models), ``EpisodeState``,
  ``reset`` / ``step`` (one jitted move), ``rollout`` (a whole episode under one ``lax.scan``), the stages;
- ``sources``: where frames come from (a dataset scene, a recording, a world rendered on demand);
- ``runner``: the host driver: each module timed, a record per move;
- ``scoring``: an episode scored against its scene (matching, macro scores, coverage);
- ``setup``: an episode built from a run's config (the one owner of that wiring);
- ``protocol``: the paper's evaluation (Sec. 4) as Table 1's rows: batched runs per scene, the all-views
  upper bound, the oracle NBV, an episode's record and its scores.

The episode imports the world, perception and planning; only the commands import it.
"""

import importlib

__all__ = ["active", "protocol", "runner", "scoring", "setup", "sources"]


def __getattr__(name: str):
    if name in __all__:
        return importlib.import_module(f"jaxcls.episode.{name}")
    raise AttributeError(f"module 'jaxcls.episode' has no attribute {name!r}")
