"""``jaxcls train-policy``'s settings."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from jaxcls.config import bounded, check_bounds, load_config, resolve_config
from jaxcls.episode.protocol import Label
from jaxcls.experiments.policy.ppo import PPOConfig
from jaxcls.experiments.table1.config import SceneSource, Table1Config
from jaxcls.planning.learned import Base, Layout


@dataclasses.dataclass(frozen=True)
class PolicyConfig:
    """The learned view policy's imitation of the oracle (DAgger) for one Table 1 config and classifier.

    Each round rolls out ``runs`` episodes on each of the ``train_scenes`` training scenes: the oracle tries
    every candidate at every move and labels it with its true F1; the runs go where the oracle goes with
    probability ``beta ** round`` (round 0: always), else where the network goes. The network is fitted on every
    round's decisions so far, then evaluated on ``eval_scenes`` held-out scenes (the Table 1 config's first
    scenes) against VisOcclHistGR and InfoGainGR, with GR on.
    """

    out_dir: str = "runs/policy"
    table1: str = "table1_real_like"  # the Table 1 config (name or path) whose scenes, classifier, moves it serves
    table1_overrides: tuple[str, ...] = ()  # key=value changes to it
    classifier: str = ""  # one of its classifiers by name ("" = its first)
    # The training scenes are its dataset's config drawn with this seed instead (rendered where the episodes run,
    # none written): other scenes than its own, which are the held-out ones.
    train_seed: int = 1001
    train_scenes: int = bounded(16, ge=1)
    eval_scenes: int = bounded(8, ge=1)
    runs: int = bounded(4, ge=1)  # start views a training scene and round
    eval_runs: int = bounded(2, ge=1)  # start views a held-out scene
    rounds: int = bounded(3, ge=0)  # DAgger rounds (may grow when a run resumes; 0: PPO straight from the start)
    beta: float = bounded(0.5, ge=0.0, le=1.0)  # round r follows the oracle with probability beta ** r
    epochs: int = bounded(30, ge=1)  # passes over every decision so far, each round
    # The share of the training scenes whose decisions the fit leaves out (the draw's last ceil(share x
    # train_scenes)): its loss, regret and agreement on them each round (``val_*`` in metrics.json), the
    # imitation's overfitting measured on states of its own rounds. PPO still trains on every training scene.
    validation: float = bounded(0.0, ge=0.0, lt=1.0)
    early_stop: bool = False  # each round keeps the epoch of least validation loss (needs validation > 0)
    batch: int = bounded(64, ge=1)
    learning_rate: float = bounded(1e-3, gt=0.0)
    hidden: int = bounded(64, ge=1)  # the network's width (``learned.ViewScorer``)
    layout: Layout = Layout.v2  # the network's input (``learned.Layout``; v3: v2 and where a view sees a segment from)
    base: Base = Base.info_gain  # the hand-made policy the network starts as exactly (none: a random network)
    # Or a trained policy's weights (a shipped name of ``learned.SHIPPED_WEIGHTS`` or a .msgpack with its .json, of
    # width ``hidden``) it starts from instead: to go on from a shipped policy, e.g. PPO alone with ``rounds: 0``.
    init: str = ""
    # A candidate's label: its true F1 after its move (greedy: the oracle row's), or at T with ``base`` taking the
    # moves after it (rollout: one step of policy improvement over ``base``; ``base`` must name a policy).
    labels: Label = Label.greedy
    temperature: float = bounded(0.02, gt=0.0)  # the target: softmax((F1 - best F1) / temperature) over the choices
    seed: int = 0  # starts, keys, the network's initialisation, the batches, the DAgger draws
    # Then reinforcement: PPO updates from the imitated policy, on the training scenes (``ppo.updates``: 0, none).
    ppo: PPOConfig = dataclasses.field(default_factory=PPOConfig)

    def __post_init__(self) -> None:
        check_bounds(self)
        if self.rounds == 0 and self.ppo.updates == 0:
            raise ValueError("rounds: 0 and ppo.updates: 0 train nothing; give either some")
        if self.ppo.new_scenes > self.train_scenes:
            raise ValueError(f"ppo.new_scenes: {self.ppo.new_scenes} scenes replaced an update, more than the "
                             f"train_scenes = {self.train_scenes} in memory; give at most {self.train_scenes}")
        if self.early_stop and not self.validation:
            raise ValueError("early_stop: true picks each round's epoch by the validation loss; validation is 0 "
                             "(hold out a share of the training scenes, e.g. validation=0.25)")
        if self.rounds and self.validation and self.validation_scenes() >= self.train_scenes:
            raise ValueError(f"validation: {self.validation} of train_scenes = {self.train_scenes} leaves no scene "
                             "to fit on; give a smaller share or more scenes")
        if self.labels is Label.rollout and self.base is Base.none:
            raise ValueError("labels: rollout continues each candidate with the base policy; base is none "
                             f"(choose one of {[b.value for b in Base if b is not Base.none]})")

    def table1_config(self) -> Table1Config:
        """The Table 1 config (its own scenes: the held-out ones)."""
        return load_config(Table1Config, resolve_config(self.table1), self.table1_overrides)

    def training_config(self) -> Table1Config:
        """The Table 1 config over the training scenes: its dataset's config drawn with ``train_seed`` and
        rendered where the episodes run: ``train_scenes`` of them, and as many as PPO's window slides over
        (``ppo.new_scenes``; a scene is the same whatever their count). Refused where that is its own seed (the
        scenes would be the held-out ones)."""
        from jaxcls.experiments.table1.data import dataset_config

        held_out = self.table1_config()
        dataset = dataset_config(held_out)
        if dataset.seed == self.train_seed:
            raise ValueError(f"train_seed: {self.train_seed} is the seed of {self.table1}'s own (held-out) scenes; "
                             "choose another")
        return dataclasses.replace(held_out, scene_source=SceneSource.device, scenes=self.train_scenes,
                                   dataset_overrides=(*held_out.dataset_overrides, f"seed={self.train_seed}",
                                                      f"num_scenes={self.stream_scenes()}"))

    def validation_scenes(self) -> int:
        """How many training scenes the imitation's fit leaves out (the draw's last: ceil(validation x
        train_scenes); 0 for none)."""
        return math.ceil(self.validation * self.train_scenes - 1e-9)  # (0.1 x 30 is 3.0000000000000004)

    def stream_scenes(self) -> int:
        """The training scenes the run draws: ``train_scenes``, and ``ppo.new_scenes`` more for each PPO update
        after the first."""
        return self.train_scenes + max(self.ppo.updates - 1, 0) * self.ppo.new_scenes

    def classifier_name(self, config: Table1Config) -> str:
        """``classifier``, or the Table 1 config's first; ValueError naming the choices."""
        name = self.classifier or next(iter(config.classifiers))
        if name not in config.classifiers:
            raise ValueError(f"classifier: {name!r} is not one of {self.table1}'s classifiers "
                             f"{list(config.classifiers)}")
        return name

    def results_defining(self) -> dict:
        """What a run's decisions and weights depend on (a resumed run must keep them; ``rounds`` and
        ``ppo.updates`` may grow, ``rounds`` only until the updates begin)."""
        out = {k: v for k, v in dataclasses.asdict(self).items() if k not in ("out_dir", "rounds")}
        out["ppo"] = {k: v for k, v in out["ppo"].items() if k != "updates"}
        return out


def load(path: str | Path | None = None, overrides: tuple[str, ...] = ()) -> PolicyConfig:
    """A policy config: a shipped name or a path (``resolve_config``), then ``overrides``."""
    return load_config(PolicyConfig, resolve_config(path) if path else None, overrides)
