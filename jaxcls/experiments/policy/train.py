"""The learned view policy trained by imitation of the oracle, DAgger-style (``jaxcls train-policy``).

Each round: the training scenes' runs are rolled out by the oracle (every candidate of every move fused,
segmented, classified, refined and scored by its true F1), each run following the oracle or the network
(``data.collect``); the network is fitted on every round's decisions so far with a listwise loss, minus the log of
the expected exp((F1 - best F1) / temperature) under its softmax over the allowed candidates (``loss``: 0 where
every candidate ties, so the network keeps its own order where the oracle sees no difference: the hand-made
policy it starts from, ``learned.init``'s ``base``); then it is evaluated on held-out scenes against VisOcclHistGR
and InfoGainGR, all in one switched program (``evaluate``). A round ends with an orbax checkpoint (the weights and the
optimiser's state) and ``metrics.json``; a run started again resumes after its last finished round, a round's
decisions kept on disk (``decisions_<r>.npz``) so that an interrupted round does not collect them again. A
round's ``seconds`` in ``metrics.json``: collecting (with ``states_per_second``, the states the oracle stepped to
and labelled: every candidate of every decision), fitting, evaluating (wall time, compilation included). The run
ends with ``policy.msgpack`` (+ ``.json``, ``learned.save``) and ``curve.png``. ``init`` starts the network from a
trained policy's weights instead of ``base``'s (with ``rounds: 0``, PPO alone from a shipped policy). With
``validation``, the decisions of the training draw's last scenes stay out of the fit and measure it (``val_*`` in
``metrics.json``); with ``early_stop`` each round keeps its epoch of least validation loss.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import time
import warnings
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
import orbax.checkpoint as ocp
from tqdm.auto import tqdm

from jaxcls import devices, io, metrics, viz
from jaxcls.config import load_config, save_config
from jaxcls.episode import active, batched, protocol, scoring, setup
from jaxcls.experiments.policy import ppo
from jaxcls.experiments.policy.config import PolicyConfig
from jaxcls.experiments.policy.data import Decisions, collect
from jaxcls.experiments.table1 import runner
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.experiments.table1.data import Scenes, open_scenes
from jaxcls.planning import learned, nbv
from jaxcls.world.objects import object_set_from_config

COMPARED = ("vis_occl_hist", "info_gain", "learned")  # the held-out evaluation's policies (GR on), one program


def loss(weights: dict, x: learned.Features, f1: jax.Array, allowed: jax.Array, temperature: float
         ) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
    """The listwise imitation loss of a batch of decisions ([B] leading axes) and its (regret, agreement).

    The loss is -log sum_i p_i exp((F1_i - best F1) / temperature), p the network's softmax over the allowed
    candidates, averaged over the decisions: as the temperature goes to 0, minus the log of the probability it
    gives the oracle's best views (any of them: ties need not share it). A decision whose candidates all tie
    costs 0, so the network's order there stays its own (the hand-made policy it starts from). Regret [] is the
    mean true F1 given up by the network's best candidate; agreement [] the share of decisions where it is one
    of the oracle's best."""
    scores = jnp.where(allowed, learned.apply(weights, x), -1e9)
    log_p = jax.nn.log_softmax(scores, axis=-1)
    best = jnp.max(jnp.where(allowed, f1, -jnp.inf), axis=-1, keepdims=True)
    gain = jnp.where(allowed, (f1 - best) / temperature, -jnp.inf)  # <= 0, 0 at the best
    nll = -jax.nn.logsumexp(jnp.where(allowed, log_p + gain, -jnp.inf), axis=-1)
    chosen = jnp.take_along_axis(f1, jnp.argmax(scores, axis=-1)[:, None], axis=-1)
    return jnp.mean(nll), (jnp.mean(best - chosen), jnp.mean(chosen >= best))


@functools.partial(jax.jit, static_argnames=("optimizer", "batch", "temperature"))
def _epoch(weights: dict, opt_state: Any, data: Decisions, key: jax.Array, optimizer: optax.GradientTransformation,
           batch: int, temperature: float) -> tuple[dict, Any, jax.Array]:
    """One pass over ``data`` in shuffled batches of ``batch`` (the last partial one left out) under one
    ``lax.scan``: the new weights and optimiser state, and [steps, 3] each step's (loss, regret, agreement)."""
    steps = len(data) // batch
    order = jax.random.permutation(key, len(data))[:steps * batch].reshape(steps, batch)

    def step(carry, rows):
        w, s = carry
        part = jax.tree.map(lambda a: a[rows], data)
        (value, (regret, agree)), grads = jax.value_and_grad(loss, has_aux=True)(
            w, part.features, part.f1, part.allowed, temperature)
        updates, s = optimizer.update(grads, s, w)
        return (optax.apply_updates(w, updates), s), jnp.stack([value, regret, agree])

    (weights, opt_state), per_step = jax.lax.scan(step, (weights, opt_state), order)
    return weights, opt_state, per_step


@functools.partial(jax.jit, static_argnames=("temperature",))
def _measure(weights: dict, data: Decisions, temperature: float) -> jax.Array:
    """[3] the loss, regret and agreement of ``weights`` on all of ``data`` (``loss``)."""
    value, (regret, agree) = loss(weights, data.features, data.f1, data.allowed, temperature)
    return jnp.stack([value, regret, agree])


def fit(weights: dict, opt_state: Any, optimizer: optax.GradientTransformation, data: Decisions, epochs: int,
        batch: int, temperature: float, key: jax.Array, validation: Decisions | None = None,
        early_stop: bool = False) -> tuple[dict, Any, dict[str, Any]]:
    """``epochs`` passes over ``data`` (batches of ``min(batch, len(data))``); the last epoch's mean loss, regret
    and agreement. With ``validation`` (decisions of other scenes), also the loss, regret and agreement on them
    after every epoch (``val_loss``, ``val_regret``, ``val_agreement``: the kept epoch's; ``val_losses``: every
    epoch's), and with ``early_stop`` the weights and optimiser state of the epoch of least (finite) validation
    loss (``epoch``: the one kept, from 1; its training figures are that epoch's). The training figures are means
    over the epoch's steps, the validation ones those of the weights after it."""
    if early_stop and validation is None:
        raise ValueError("fit: early_stop needs validation decisions")
    batch = min(batch, len(data))
    on_device = jax.device_put(data)
    held = None if validation is None else jax.device_put(validation)
    kept, per_epoch, val = None, [], []
    for epoch in range(epochs):
        weights, opt_state, per_step = _epoch(weights, opt_state, on_device, jax.random.fold_in(key, epoch),
                                              optimizer, batch, temperature)
        per_epoch.append(per_step)  # (on the device: read once, at the end)
        if held is not None:
            val.append(np.asarray(_measure(weights, held, temperature)))
            score = float(val[-1][0]) if math.isfinite(val[-1][0]) else math.inf  # (a NaN is never the least)
            if early_stop and (kept is None or score < kept[3]):
                kept = (epoch, weights, opt_state, score)
    at = epochs - 1
    if kept is not None:
        at, weights, opt_state, _ = kept
    value, regret, agree = (float(v) for v in np.asarray(per_epoch[at]).mean(axis=0))
    if not math.isfinite(value):
        raise RuntimeError(f"train-policy: the loss is {value}; the fit diverged (lower learning_rate?)")
    fitted: dict[str, Any] = {"loss": value, "regret": regret, "agreement": agree}
    if val:
        fitted.update({"val_loss": float(val[at][0]), "val_regret": float(val[at][1]),
                       "val_agreement": float(val[at][2]), "val_losses": [float(v[0]) for v in val],
                       "epoch": at + 1})
    return weights, opt_state, fitted


@dataclasses.dataclass
class _Scenes:
    """A scene set's frames in chunks of the Table 1 config's ``scene_chunk`` (rendered once, kept), with truths."""

    config: Table1Config
    scene_set: Scenes
    object_set: Any
    chunks: list = dataclasses.field(default_factory=list)

    def frames(self) -> list:
        """[(the chunk's scene indices, its ``Chunk``, each scene's ``Truth``)] of every chunk, made once."""
        if not self.chunks:
            indices = list(range(self.scene_set.count))
            for at in range(0, len(indices), self.config.scene_chunk):
                chunk = self.scene_set.chunk(indices[at:at + self.config.scene_chunk])
                truths = [scoring.Truth.from_scene(s, self.object_set) for s in chunk.scenes]
                self.chunks.append((indices[at:at + self.config.scene_chunk], chunk, truths))
        return self.chunks


@functools.partial(jax.jit, donate_argnums=0)
def _put(pool: jax.Array, slots: jax.Array, values: jax.Array) -> jax.Array:
    """``pool`` [P, ...] with rows ``slots`` [S] set to ``values`` [S, ...], in place (its buffer donated)."""
    return pool.at[slots].set(values)


@dataclasses.dataclass
class _Window:
    """PPO's training scenes in memory: ``training``'s ``size`` scenes' frames (depth [size, V, H, W] m, T_wc [size,
    V, 4, 4] f32, on the device) and truths (``TruthArrays`` padded to the scenes' object count), scene ``i`` of the
    training draw in slot ``i % size``. Update u (from 0) sees scenes [u * step, u * step + size) (``step``:
    ``ppo.new_scenes``; 0, the same ``size`` scenes every update)."""

    training: _Scenes
    step: int
    scene: list[int] = dataclasses.field(init=False)  # [size] the scene in each slot (-1: none yet)
    truths: list = dataclasses.field(init=False)  # [size] ``TruthArrays``
    depth: Any = None
    T_wc: Any = None

    def __post_init__(self) -> None:
        self.scene, self.truths = [-1] * self.size, [None] * self.size

    @property
    def size(self) -> int:
        return self.training.scene_set.count

    def at(self, update: int) -> int:
        """Holds update ``update``'s scenes, rendering (or taking from the rounds' frames) those it lacks; returns
        how many it added."""
        first = update * self.step
        wanted = [i for i in range(first, first + self.size) if self.scene[i % self.size] != i]
        if not wanted:
            return 0
        objects = self.training.scene_set.dataset.scene.num_objects  # (the truths' padding: every scene's count)
        rounds = self.training.chunks  # (the rounds' frames of scenes 0.., let go one by one once in the pool)
        if first == 0 and self.depth is None and rounds:
            queue = rounds
        else:
            rounds.clear()
            step = self.training.config.scene_chunk
            queue = [(wanted[at:at + step], None, None) for at in range(0, len(wanted), step)]
        while queue:
            indices, chunk, truths = queue.pop(0)
            if chunk is None:
                chunk = self.training.scene_set.chunk(indices)
                truths = [scoring.Truth.from_scene(s, self.training.object_set) for s in chunk.scenes]
            depth, T_wc = jnp.asarray(chunk.depth, jnp.float32), jnp.asarray(chunk.T_wc, jnp.float32)
            if self.depth is None:  # (the pool, made once, committed to the frames' device; chunks go in place after)
                device = next(iter(depth.devices()))
                self.depth = jnp.zeros((self.size, *depth.shape[1:]), jnp.float32, device=device)
                self.T_wc = jnp.zeros((self.size, *T_wc.shape[1:]), jnp.float32, device=device)
            slots = jnp.asarray([i % self.size for i in indices], jnp.int32)
            self.depth, self.T_wc = _put(self.depth, slots, depth), _put(self.T_wc, slots, T_wc)
            for i, truth in zip(indices, truths, strict=True):
                self.scene[i % self.size] = i
                self.truths[i % self.size] = scoring.TruthArrays.of(truth, objects)
            del chunk, depth
        jax.block_until_ready((self.depth, self.T_wc))
        return len(wanted)


def _runs(seed: int, scenes: list[int], runs: int, views: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(scene position [R], start [R], keys [R]) of ``runs`` runs of each scene (Table 1's starts and keys)."""
    at = np.repeat(np.arange(len(scenes)), runs)
    starts = np.concatenate([protocol.start_views(seed, s, runs, views) for s in scenes])
    with jax.default_device(devices.host_cpu()):  # (keys on the host: nothing waits for a GPU)
        keys = np.concatenate([np.asarray(protocol.run_keys(seed, s, runs)) for s in scenes])
    return at.astype(np.int32), starts, keys


def evaluate(switched: active.Episode, weights: dict, held_out: _Scenes, runs: int, seed: int,
             moves: int) -> dict[str, Any]:
    """Macro F1 of the target objects after the last move on the held-out scenes (their first ``runs`` runs, Table
    1's starts and keys), VisOcclHistGR, InfoGainGR (the best hand-made policy in Table 1, the default ``base``)
    and the learned policy in one switched program, GR on; the paired differences learned - each of the two with
    their scene-bootstrap intervals."""
    switched = switched.replace(policy_weights=weights)
    records: dict[str, list] = {p: [] for p in COMPARED}
    for scenes, chunk, truths in held_out.frames():
        at, starts, keys = _runs(seed, scenes, runs, chunk.T_wc.shape[1])
        for policy in COMPARED:
            traces = batched.rollouts(switched.choose(policy, True), chunk.depth, chunk.T_wc, at, starts, keys)
            records[policy] += protocol.episode_records(
                traces, [truths[a] for a in at], [{"scene": scenes[a], "run": r % runs} for r, a in enumerate(at)])
    classes = len(switched.spec.classifier.classes)
    per = {p: protocol.per_scene(records[p], moves) for p in COMPARED}
    out: dict[str, Any] = {f"f1_{p}": metrics.scene_interval(per[p], classes, resamples=200)[0] for p in COMPARED}
    for other in COMPARED[:-1]:
        out[f"learned_minus_{other}"] = list(metrics.paired_difference(per["learned"], per[other], classes,
                                                                       resamples=200))
    return out


def initial_weights(config: PolicyConfig, max_candidates: int, classifier: str = "") -> dict:
    """The network's first weights: those of ``config.init`` (a shipped name or a policy file, of width ``hidden``
    and ``max_candidates`` candidates, else a ValueError naming both; a warning where the file was trained for
    another ``classifier``), else ``base``'s exactly (``learned.init``)."""
    if not config.init:
        return learned.init(jax.random.key(config.seed), config.hidden, config.base, config.layout)
    weights, info = learned.load(config.init, max_candidates)
    if info.hidden != config.hidden:
        raise ValueError(f"init: {config.init} is a network of width {info.hidden}; hidden is {config.hidden} "
                         f"(set hidden={info.hidden})")
    if info.features is not config.layout:
        raise ValueError(f"init: {config.init} reads feature layout {info.features.value}; layout is "
                         f"{config.layout.value} (set layout={info.features.name})")
    trained_for = info.metadata.get("classifier")
    if classifier and trained_for and trained_for != classifier:
        warnings.warn(f"init: {config.init} was trained for classifier {trained_for!r}; this run trains it for "
                      f"{classifier!r}", stacklevel=2)
    return weights


@functools.cache
def _init_digest(init: str) -> str:
    """The SHA-256 of the weights file ``init`` names ("" for none): which weights a run started from (read once a
    process, not at every ``publish``)."""
    if not init:
        return ""
    return hashlib.sha256(learned.weights_file(init).read_bytes()).hexdigest()


def _resume_point(out: Path, config: PolicyConfig, manager: ocp.CheckpointManager) -> int:
    """The rounds a run folder finished (0 for a new one), once this config continues it (``rounds`` may grow)."""
    done = manager.latest_step() or 0
    saved = out / "config.yaml"
    if saved.is_file():
        before = load_config(PolicyConfig, saved).results_defining()
        changed = sorted(k for k, v in config.results_defining().items() if before.get(k) != v)
        if changed:
            raise ValueError(f"train-policy: {out} holds a run with other settings ({', '.join(changed)} differ from "
                             f"{saved}); resume with the same config or choose another out_dir")
        rounds_before = load_config(PolicyConfig, saved).rounds
        if done > rounds_before and config.rounds != rounds_before:
            raise ValueError(f"train-policy: {out} began its PPO updates after {rounds_before} rounds; rounds stays "
                             f"{rounds_before} (got {config.rounds})")
    if done > config.rounds + config.ppo.updates:
        raise ValueError(f"train-policy: {out} has finished {done} rounds and updates already, more than rounds + "
                         f"ppo.updates = {config.rounds + config.ppo.updates}")
    return done


def train(config: PolicyConfig, show_progress: bool = True) -> Path:
    """Run (or resume) a training; returns the run folder (``policy.msgpack``, ``metrics.json``, ``curve.png``)."""
    out = Path(config.out_dir)
    manager = ocp.CheckpointManager(out.resolve() / "checkpoints")
    start = _resume_point(out, config, manager)
    held_out_config = dataclasses.replace(config.table1_config(), scenes=config.eval_scenes)
    name = config.classifier_name(held_out_config)
    weights = initial_weights(config, held_out_config.nbv.max_candidates, name)  # (checked before the run is kept)
    save_config(config, out / "config.yaml")
    training_config = config.training_config()
    dataset, train_set = open_scenes(training_config)
    _, eval_set = open_scenes(held_out_config)
    object_set = object_set_from_config(dataset.objects)
    classifier = setup.load_classifier(held_out_config.classifiers[name], object_set, f"classifiers.{name}")
    training, held_out = _Scenes(training_config, train_set, object_set), _Scenes(held_out_config, eval_set, object_set)
    intrinsics, table_height, _ = train_set.frame_layout()  # (from the config: no frame rendered for them)
    oracle = runner.episode(held_out_config, protocol.ROWS["oracle_gr"], classifier, object_set, intrinsics,
                            table_height, dataset.scene.split, name=name)
    if config.labels is protocol.Label.rollout:  # (the labels' continuations: the base policy's moves)
        oracle = oracle.replace(config=dataclasses.replace(oracle.config, policy=nbv.PolicyName(config.base.value)))

    optimizer = optax.adam(config.learning_rate)
    opt_state = optimizer.init(weights)
    params = {"actor": weights, "critic": learned.init(jax.random.key(config.seed + 2), config.hidden,
                                                       layout=config.layout)}
    rl_state = ppo.optimizer(config.ppo).init(params)
    history: list[dict] = []
    if start:
        saved = ({"weights": weights, "opt_state": opt_state} if start <= config.rounds
                 else {"params": params, "opt_state": rl_state})
        restored = manager.restore(start, args=ocp.args.StandardRestore(
            jax.tree.map(ocp.utils.to_shape_dtype_struct, saved)))
        if start <= config.rounds:
            weights, opt_state = restored["weights"], restored["opt_state"]
        else:
            params, rl_state = restored["params"], restored["opt_state"]
        history = [h for h in json.loads((out / "metrics.json").read_text())["history"]
                   if h.get("round", start + 1) <= start or h.get("update", start + 1) <= start - config.rounds]
    switched = oracle.replace(policy_weights=weights).switched(COMPARED)

    bar = tqdm(range(min(start, config.rounds), config.rounds), desc="train-policy", unit="round",
               initial=min(start, config.rounds), total=config.rounds, disable=not show_progress)
    for r in bar:
        kept, seconds = out / f"decisions_{r}.npz", {}
        began = time.perf_counter()
        if not kept.is_file():
            follow = config.beta ** r
            rng = np.random.default_rng([config.seed, r])
            parts = []
            for scenes, chunk, truths in tqdm(training.frames(), desc=f"round {r + 1}: the oracle's labels",
                                              unit="chunk", leave=False, disable=not show_progress):
                at, starts, keys = _runs(config.seed + 7919 * (r + 1), scenes, config.runs, chunk.T_wc.shape[1])
                part = collect(oracle, chunk.depth, chunk.T_wc, at, starts, keys, [truths[a] for a in at],
                               weights if r else None, follow, rng, runner.oracle_call_size(training_config),
                               config.labels, config.layout)
                parts.append(dataclasses.replace(part, scene=np.asarray(scenes, np.int32)[part.scene]))  # (the draw's)
            collected = Decisions.concatenate(parts)
            collected.save(kept)
            seconds["collect"] = time.perf_counter() - began
            seconds["states_per_second"] = collected.f1.size / seconds["collect"]  # (every candidate of every decision)
        data = Decisions.concatenate([Decisions.load(out / f"decisions_{i}.npz") for i in range(r + 1)])
        validation = None
        if config.validation_scenes():  # (the training draw's last scenes: their decisions out of the fit)
            data, validation = data.split(np.arange(config.train_scenes - config.validation_scenes(),
                                                    config.train_scenes))
        began = time.perf_counter()
        weights, opt_state, fitted = fit(weights, opt_state, optimizer, data, config.epochs, config.batch,
                                         config.temperature, jax.random.fold_in(jax.random.key(config.seed + 1), r),
                                         validation, config.early_stop)
        seconds["fit"] = time.perf_counter() - began
        began = time.perf_counter()
        scores = evaluate(switched, weights, held_out, config.eval_runs, held_out_config.seed, held_out_config.moves)
        seconds["evaluate"] = time.perf_counter() - began
        held = {} if validation is None else {"val_decisions": len(validation)}
        history.append({"round": r + 1, "decisions": len(data), **held, "follow_oracle": config.beta ** r, **fitted,
                        **scores, "seconds": seconds})
        publish(out, config, name, held_out_config.nbv.max_candidates, weights, history)
        manager.save(r + 1, args=ocp.args.StandardSave({"weights": weights, "opt_state": opt_state}))
        bar.set_postfix(loss=f"{fitted['loss']:.3f}", regret=f"{fitted['regret']:.3f}",
                        learned=f"{scores['f1_learned']:.3f}", info_gain=f"{scores['f1_info_gain']:.3f}")
    if config.ppo.updates:
        if start <= config.rounds:  # (the imitated policy, a fresh critic and optimiser)
            params = {"actor": weights, "critic": params["critic"]}
            rl_state = ppo.optimizer(config.ppo).init(params)
        weights = _reinforce(config, out, manager, params, rl_state, oracle, switched, training, held_out,
                             held_out_config, max(start - config.rounds, 0), history, name, show_progress)
    manager.wait_until_finished()
    publish(out, config, name, held_out_config.nbv.max_candidates, weights, history)
    return out


def publish(out: Path, config: PolicyConfig, name: str, max_candidates: int, weights: dict,
            history: list[dict]) -> None:
    """The run's figures so far (``metrics.json``, ``curve.png``) and its weights (``policy.msgpack`` + ``.json``),
    each written atomically after every round and update: a run stopped anywhere leaves the policy of its last
    finished step, ready for ``nbv.learned.weights``."""
    io.write_json(out / "metrics.json", {"table1": config.table1, "classifier": name, "history": history})
    viz.save(viz.policy_curve(history), out / "curve.png")
    learned.save(out / "policy.msgpack", weights, max_candidates, {
        "trained_by": "jaxcls train-policy", "table1": config.table1, "classifier": name, "base": config.base.value,
        "init": config.init, "init_sha256": _init_digest(config.init),
        "labels": config.labels.value, "rounds": sum("round" in h for h in history),
        "ppo_updates": sum(h.get("update", 0) > 0 for h in history),
        # (the last held-out evaluation, with its round or update: after a PPO update, maybe an earlier one's)
        "held_out": next(({k: v for k, v in h.items() if k.startswith(("f1_", "learned_")) or k in ("round", "update")}
                          for h in reversed(history) if "f1_learned" in h), {})})


def _reinforce(config: PolicyConfig, out: Path, manager: ocp.CheckpointManager, params: dict, rl_state: Any,
               oracle: active.Episode, switched: active.Episode, training: _Scenes, held_out: _Scenes,
               held_out_config: Table1Config, done: int, history: list[dict], name: str, show_progress: bool) -> dict:
    """PPO updates ``done``..``ppo.updates`` on ``runs`` x ``ppo.group`` episodes of each training scene in memory
    (new starts each update, each start's ``ppo.group`` episodes together; the scenes a ``_Window`` of the training
    draw: ``ppo.new_scenes`` new ones each update), each checkpointed as step ``rounds + update``, evaluated on the
    held-out scenes every ``ppo.eval_every`` updates and after the last (and before the first where there were no
    imitation rounds: ``update`` 0). Returns the actor's weights."""
    if oracle.config.moves < 2:
        raise ValueError(f"train-policy: PPO needs episodes of at least 2 moves (decisions after the first); "
                         f"{config.table1} has moves = {oracle.config.moves}")
    window = _Window(training, config.ppo.new_scenes)
    env = oracle.replace(config=dataclasses.replace(oracle.config, policy=nbv.PolicyName.random))  # (overridden)
    if done == 0 and config.rounds == 0:  # (PPO alone: the starting policy's held-out figures, as update 0)
        history.append({"update": 0, **evaluate(switched, params["actor"], held_out, config.eval_runs,
                                                held_out_config.seed, held_out_config.moves)})
        publish(out, config, name, held_out_config.nbv.max_candidates, params["actor"], history)
    key = jax.random.key(config.seed + 3)
    bar = tqdm(range(done, config.ppo.updates), desc="train-policy: PPO", unit="update", initial=done,
               total=config.ppo.updates, disable=not show_progress)
    for u in bar:
        began = time.perf_counter()
        moved_in = window.at(u)  # (the scenes whose frames it rendered or moved into the window)
        added = {"new_scenes": time.perf_counter() - began} if moved_in else {}
        scenes_in = {"scenes": [min(window.scene), max(window.scene)]}  # (the window's first and last scene)
        began = time.perf_counter()
        at, starts, _ = _runs(config.seed + 104729 * (u + 1), window.scene, config.runs, window.T_wc.shape[1])
        at, starts = np.repeat(at, config.ppo.group), np.repeat(starts, config.ppo.group)  # (ppo.group's episodes)
        episode_truths = jax.tree.map(lambda *xs: np.stack(xs), *[window.truths[a] for a in at])
        # (committed where the frames are, as the update's outputs are: the first update's inputs then place like
        # every later one's, and ``ppo.update`` compiles once, not twice; BENCHMARKS.md, "the slow second update")
        params, rl_state = jax.device_put((params, rl_state), window.depth.sharding)
        params, rl_state, figures = ppo.update(params, rl_state, env, window.depth, window.T_wc, jnp.asarray(at),
                                               jnp.asarray(starts, jnp.int32), episode_truths,
                                               jax.random.fold_in(key, u), config.ppo)
        entry: dict[str, Any] = {"update": u + 1, **{k: float(v) for k, v in figures.items()}, **scenes_in}
        entry["seconds"] = {"update": time.perf_counter() - began,
                            "moves_per_second": len(at) * env.config.moves / (time.perf_counter() - began),
                            **added}
        if (u + 1) % config.ppo.eval_every == 0 or u + 1 == config.ppo.updates:
            began = time.perf_counter()
            entry.update(evaluate(switched, params["actor"], held_out, config.eval_runs, held_out_config.seed,
                                  held_out_config.moves))
            entry["seconds"]["evaluate"] = time.perf_counter() - began
        history.append(entry)
        began = time.perf_counter()
        publish(out, config, name, held_out_config.nbv.max_candidates, params["actor"], history)
        manager.save(config.rounds + u + 1, args=ocp.args.StandardSave({"params": params, "opt_state": rl_state}))
        entry["seconds"]["kept"] = time.perf_counter() - began  # (in metrics.json from the next update's on)
        bar.set_postfix(f1=f"{entry['f1_last']:.3f}", entropy=f"{entry['entropy']:.3f}")
    return params["actor"]


__all__ = ["COMPARED", "evaluate", "fit", "initial_weights", "loss", "train"]
