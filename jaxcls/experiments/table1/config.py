"""Table 1's settings: which scenes, rows, runs and classifiers, and the move's settings."""

from __future__ import annotations

import dataclasses
import enum
from pathlib import Path
from typing import Any

from jaxcls.config import bounded, check_bounds, load_config
from jaxcls.episode import active, batched, protocol, setup
from jaxcls.perception.refine import RefineConfig
from jaxcls.perception.settings import PerceptionConfig
from jaxcls.planning import learned
from jaxcls.planning.nbv import WEIGHTED as NBV_WEIGHTED
from jaxcls.planning.nbv import NBVConfig


class SceneSource(enum.StrEnum):
    """Where Table 1's frames come from: ``dataset``, the files ``jaxcls dataset`` wrote (rendered first where
    missing; the reference); ``device``, the dataset config's scenes drawn with its seeds and rendered chunk by
    chunk where the episodes run (the scene bank on the GPU; MuJoCo's C caster on a CPU), never written."""

    dataset = "dataset"
    device = "device"


@dataclasses.dataclass(frozen=True)
class Table1Config:
    """``experiments/table1.py``: which scenes, rows, runs and classifiers; the move's settings."""

    out_dir: str = "runs/table1_synthetic"
    dataset: str = "synthetic"  # a dataset config (name or path) or a folder written by ``jaxcls dataset``
    dataset_overrides: tuple[str, ...] = ()  # key=value changes to a dataset config (num_scenes, out_dir, ...)
    scene_source: SceneSource = SceneSource.dataset  # the dataset's files, or its scenes rendered on the device
    seed: int = 0  # start views and episode keys
    scenes: int = bounded(0, ge=0)  # the first this many scenes of the dataset; 0 = all
    runs: int = bounded(10, ge=1)  # episodes per scene and row, from random start views
    moves: int = bounded(10, ge=1)  # T
    rows: tuple[str, ...] = protocol.PAPER_ROWS
    oracle_scenes: int = bounded(7, ge=0)  # the oracle row runs on the first this many scenes
    # The oracle's episodes tried together (each tries every candidate at every move: episodes x candidates
    # moves in one vmapped call, ~45 MB each at 640x480), its episodes in (scene, run) order, the same calls for
    # every process count (``runner.oracle_calls``). 0: 64 on an accelerator (``ORACLE_EPISODES_PER_CALL``),
    # one at a time on the CPU (no faster there).
    oracle_runs_per_call: int = bounded(0, ge=0)
    # The single-view and policy rows run batched over scenes and runs (``episode.batched``): the frames of
    # this many scenes (rounded up to a multiple of the devices) sit in device memory at once, split over the
    # devices (100 views at 640x480: 123 MB a scene), and at most ``batch_episodes`` episodes run in one call
    # (0: all of a row's episodes of those scenes; a call holds whole scenes, as many on every device, so at
    # least devices x runs episodes). To keep a device's share as on one device, scale both with the devices.
    scene_chunk: int = bounded(8, ge=1)
    batch_episodes: int = bounded(0, ge=0)
    # How XLA picks the GPU kernels of that program and of the oracle's (``batched.Kernels``): ``fixed`` compiles
    # to the same kernels every time, so a rerun, a resumed run and a run over more devices or processes give the
    # same records; ``autotuned`` (XLA's default) times candidates while compiling: as fast here, twice the
    # compile time, and two compilations may differ in the last bits, which near-ties carry into paths
    # (BENCHMARKS.md).
    kernels: batched.Kernels = batched.Kernels.fixed
    # name: weights (a .msgpack path or a shipped name, "" = the shipped weights); no default, so that a
    # config's own list is the whole list (OmegaConf merges mappings into the defaults).
    classifiers: dict[str, str] = dataclasses.field(default_factory=dict)
    # Per classifier, the learned policy's weights where they are not ``nbv.learned.weights`` (a shipped name or a
    # policy.msgpack): a policy is trained for one classifier (``jaxcls train-policy``'s ``classifier``).
    learned_weights: dict[str, str] = dataclasses.field(default_factory=dict)
    decision: active.Decision = "evidence"  # how a segment's class is decided (``active.EpisodeConfig``)
    perception: PerceptionConfig = dataclasses.field(default_factory=setup.episode_perception)
    refine: RefineConfig = dataclasses.field(default_factory=setup.episode_refine)
    nbv: NBVConfig = dataclasses.field(default_factory=setup.episode_nbv)
    timing_moves: int = bounded(10, ge=0)  # one VisOcclHistGR episode timed module by module (0 = none)
    resamples: int = bounded(2000, ge=100)  # bootstrap resamples

    def __post_init__(self) -> None:
        check_bounds(self)
        if not self.classifiers:
            raise ValueError("classifiers: name at least one (name: path, \"\" = the shipped weights)")
        if unknown := sorted(set(self.learned_weights) - set(self.classifiers)):
            raise ValueError(f"learned_weights: {unknown} not among the classifiers {list(self.classifiers)}")
        without = [c for c in self.classifiers if not self.nbv_of(c).learned.weights]
        for name in self.rows:
            if protocol.row(name, "rows").policy in NBV_WEIGHTED and without:
                raise ValueError(f"rows: {name} runs the learned policy; name its weights with nbv.learned.weights "
                                 f"or, per classifier, learned_weights (a policy.msgpack written by jaxcls "
                                 f"train-policy, or a shipped name: {', '.join(learned.SHIPPED_WEIGHTS)}); none for "
                                 f"{without}")

    def nbv_of(self, classifier: str) -> NBVConfig:
        """The move's NBV settings for ``classifier``'s episodes: ``nbv`` with its learned policy's weights from
        ``learned_weights`` where that names them."""
        weights = self.learned_weights.get(classifier)
        if not weights:
            return self.nbv
        return dataclasses.replace(self.nbv, learned=dataclasses.replace(self.nbv.learned, weights=weights))

    def results_defining(self) -> dict[str, Any]:
        """What the stored episodes depend on (a rerun with another of these must use another out_dir)."""
        return {k: v for k, v in dataclasses.asdict(self).items()
                if k not in ("out_dir", "rows", "oracle_scenes", "oracle_runs_per_call", "timing_moves", "resamples",
                             "scenes", "scene_chunk", "batch_episodes", "kernels")}


def check_out_dir(config: Table1Config, out: Path) -> None:
    """An ``out_dir`` holding episodes of another config is refused (its records would mix)."""
    previous = out / "config.yaml"
    if previous.exists() and any(out.glob("episodes*.jsonl*")):  # one process's store or several's, or archives
        old = load_config(Table1Config, previous)
        if old.results_defining() != config.results_defining():
            changed = sorted(k for k, v in config.results_defining().items() if old.results_defining().get(k) != v)
            raise ValueError(f"{previous}: out_dir holds episodes of another config (keys {changed} differ); "
                             "choose another out_dir")
