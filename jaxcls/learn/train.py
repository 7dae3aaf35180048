"""Train the PointNet classifier: ``jaxcls train [--config pointnet] [key=value ...]``.

PureJaxRL-style: the training clouds live on the device, and one epoch (sampling, augmentation, forward,
backward, Adam) is a single jitted ``lax.scan``. With several devices the batch is split over them
(``jax.sharding``, data parallel, parameters replicated). After each epoch the held-out instances are
evaluated, an orbax checkpoint is written and ``metrics.json`` updated (and the epoch's scalars logged for
TensorBoard in ``tensorboard/``), so an interrupted run resumes from its last epoch with the same result. The
run folder ends with ``pointnet.msgpack`` (+ ``.json``), the training curve and the confusion matrices.

The paper's recipe (Sec. 4): complete-surface clouds of 2500 points, zero mean, unit sphere, random yaw,
Adam at 1e-3 halved every 20 epochs, 250 epochs (``schedule: halving``); ``mix`` adds the partial-view sources
of ``clouds``. ``schedule: cosine`` decays the rate along a half cosine to ``final_lr`` of it at the last epoch:
on the shipped recipe, 80 such epochs reach the held-out NLL and accuracies of the paper's 250 (RESULTS.md,
"The learning-rate schedule"); ``configs/pointnet_folder.yaml`` (your own models) uses it.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
import orbax.checkpoint as ocp
from flax import struct
from flax.training import train_state
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from omegaconf import OmegaConf
from sklearn.metrics import confusion_matrix
from tqdm.auto import tqdm

from jaxcls import geometry, io, viz
from jaxcls.config import bounded, check_bounds, load_config, save_config
from jaxcls.learn.clouds import SOURCES, CloudConfig, CloudSet, load_clouds, sample_batch
from jaxcls.learn.logs import ScalarLog
from jaxcls.perception import pointnet
from jaxcls.perception.settings import PerceptionConfig
from jaxcls.world.objects import ObjectSetConfig, object_set_from_config

# What a run's test accuracy is measured on (metrics.json "evaluated_on").
EVALUATED_ON = {"test": "held-out instances", "train": "held-out views and poses of the training instances"}

class Schedule(enum.StrEnum):
    """How the learning rate falls over a run (``schedule:`` in the config)."""

    halving = "halving"  # the paper's: halved every ``lr_halving_epochs`` epochs (staircase)
    cosine = "cosine"  # along a half cosine from ``learning_rate`` to ``final_lr`` x it at the last epoch


@dataclasses.dataclass(frozen=True)
class Mix:
    """Relative frequency of each cloud source in training batches (0 = unused)."""

    full: float = bounded(1.0, ge=0.0)
    view: float = bounded(0.0, ge=0.0)
    occluded: float = bounded(0.0, ge=0.0)
    fused: float = bounded(0.0, ge=0.0)
    scene: float = bounded(0.0, ge=0.0)  # segments of cluttered scenes (``data.scenes`` of them)

    def __post_init__(self) -> None:
        check_bounds(self, "mix.")
        if sum(getattr(self, s) for s in SOURCES) <= 0:
            raise ValueError(f"train: mix weights must be >= 0 and not all 0, got {self} (set e.g. mix.full=1)")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """``jaxcls train``. Defaults are the paper's recipe; the shipped ``pointnet`` config adds partial views."""

    name: str = "pointnet"
    out_dir: str = "runs/pointnet"
    seed: int = 0
    objects: ObjectSetConfig = dataclasses.field(default_factory=lambda: ObjectSetConfig(surface_samples=2500))
    data: CloudConfig = dataclasses.field(default_factory=CloudConfig)
    mix: Mix = dataclasses.field(default_factory=Mix)
    model: pointnet.ModelConfig = dataclasses.field(default_factory=pointnet.ModelConfig)
    # The loop the classifier trains for: its foreground and TSDF volume make the partial clouds.
    perception: PerceptionConfig = dataclasses.field(default_factory=PerceptionConfig)
    epochs: int = bounded(250, ge=1)
    steps_per_epoch: int = bounded(0, ge=0)  # 0: one pass over the training clouds the mix draws from
    batch_size: int = bounded(32, ge=1)
    learning_rate: float = bounded(1e-3, gt=0.0)
    schedule: Schedule = Schedule.halving
    lr_halving_epochs: int = bounded(20, ge=1)  # schedule halving
    final_lr: float = bounded(0.01, ge=0.0, le=1.0)  # schedule cosine: the last epoch's rate / learning_rate
    jitter: float = bounded(0.01, ge=0.0)  # std of Gaussian noise on normalised points (clipped at 5 sigma)
    eval_rotations: int = bounded(8, ge=1)  # each held-out complete cloud is evaluated at this many yaws
    eval_batch: int = bounded(256, ge=1)
    keep_checkpoints: int = bounded(2, ge=1)
    tensorboard: bool = True  # each epoch's scalars also to out_dir/tensorboard (``jaxcls.learn.logs``)

    def __post_init__(self) -> None:
        check_bounds(self, "")


class TrainState(train_state.TrainState):
    """Flax's train state plus the batch-norm statistics."""

    batch_stats: Any


@struct.dataclass
class Bank:
    """Training clouds on the device: points [C, S, 3] m, mask [C, S], label [C] i32, the probability
    [C] f32 of drawing each (the mix spread over its source's clouds), yaw [C] f32 rad (the instance's)."""

    points: jax.Array
    mask: jax.Array
    label: jax.Array
    probability: jax.Array
    yaw: jax.Array


def make_bank(clouds: CloudSet, mix: Mix) -> Bank:
    """The training clouds as a device ``Bank``; each source's share of ``mix`` is spread over its clouds."""
    weight = np.zeros(len(clouds))
    for i, source in enumerate(SOURCES):
        members = clouds.source == i
        share = getattr(mix, source)
        if share > 0 and not members.any():
            raise ValueError(f"train: mix.{source} = {share} but the data config makes no '{source}' clouds")
        weight[members] = share / max(members.sum(), 1)
    return Bank(jnp.asarray(clouds.points), jnp.asarray(clouds.mask), jnp.asarray(clouds.label),
                jnp.asarray(weight / weight.sum(), jnp.float32), jnp.asarray(clouds.yaw, jnp.float32))


def learning_rate(config: TrainConfig, steps_per_epoch: int) -> optax.Schedule:
    """The rate at each optimiser step (``config.schedule``)."""
    if config.schedule is Schedule.cosine:
        return optax.cosine_decay_schedule(config.learning_rate, config.epochs * steps_per_epoch, config.final_lr)
    return optax.exponential_decay(config.learning_rate, config.lr_halving_epochs * steps_per_epoch, 0.5,
                                   staircase=True)


def create_state(config: TrainConfig, num_classes: int, steps_per_epoch: int) -> TrainState:
    """Fresh weights and Adam at ``learning_rate(config, steps_per_epoch)``."""
    variables = pointnet.init_variables(jax.random.key(config.seed), num_classes, config.model)
    schedule = learning_rate(config, steps_per_epoch)
    return TrainState.create(apply_fn=pointnet.make_model(num_classes, config.model).apply, params=variables["params"],
                             batch_stats=variables["batch_stats"], tx=optax.adam(schedule))


def _prepare(key: jax.Array, points: jax.Array, mask: jax.Array, jitter: float) -> tuple[jax.Array, jax.Array]:
    """A training batch as the network sees it: normalised (as ``classify`` does), then jittered."""
    points, mask = pointnet.normalise(points, mask)
    noise = jnp.clip(jitter * jax.random.normal(key, points.shape), -5 * jitter, 5 * jitter)
    return jnp.where(mask[..., None], points + noise, 0.0), mask


def yaw_loss(head: jax.Array, labels: jax.Array, yaw: jax.Array, orders: jax.Array) -> jax.Array:
    """The yaw head's loss: mean over the clouds of a class with a finite symmetry order s of the squared
    distance between the head's (cos, sin) for the true class and (cos s yaw, sin s yaw).

    head: [B, M, 2]; labels: [B] i32; yaw: [B] rad; orders: [M] i32 (0 = continuous: no yaw to learn)."""
    s = orders[labels].astype(yaw.dtype)
    target = jnp.stack([jnp.cos(s * yaw), jnp.sin(s * yaw)], axis=-1)
    pred = jnp.take_along_axis(head, labels[:, None, None], axis=1)[:, 0]
    weight = (s > 0).astype(yaw.dtype)
    return jnp.sum(weight * jnp.sum((pred - target) ** 2, axis=-1)) / jnp.maximum(jnp.sum(weight), 1.0)


def make_train_epoch(config: TrainConfig, num_classes: int, steps: int, mesh: Mesh, orders: tuple[int, ...] = ()):
    """Jitted ``(state, bank, key) -> (state, {"loss", "accuracy"} per step)``: one epoch as a scan.
    ``orders``: each class's yaw-symmetry order (``pointnet.yaw_orders``), with ``model.yaw_head``."""
    model = pointnet.make_model(num_classes, config.model)
    batch_sharding = NamedSharding(mesh, PartitionSpec("data"))
    if config.model.yaw_head and len(orders) != num_classes:
        raise ValueError(f"train: model.yaw_head needs a yaw-symmetry order per class, got {orders}")
    class_orders = jnp.asarray(orders or (0,) * num_classes, jnp.int32)

    def step(state: TrainState, key: jax.Array, bank: Bank):
        k_pick, k_sample, k_jitter, k_dropout, k_turn = jax.random.split(key, 5)
        index = jax.random.choice(k_pick, bank.label.shape[0], (config.batch_size,), p=bank.probability)
        turn = jax.random.uniform(k_turn, index.shape, minval=-jnp.pi, maxval=jnp.pi)
        points, mask = sample_batch(k_sample, bank.points, bank.mask, index, config.model.num_points, turn)
        points, mask = _prepare(k_jitter, points, mask, config.jitter)
        points, mask, labels, yaw = (jax.lax.with_sharding_constraint(a, batch_sharding)
                                     for a in (points, mask, bank.label[index], bank.yaw[index] + turn))

        def loss_fn(params):
            (logits, transform, head), updates = model.apply(
                {"params": params, "batch_stats": state.batch_stats}, points, mask, train=True,
                rngs={"dropout": k_dropout}, mutable=["batch_stats"])
            loss = optax.softmax_cross_entropy_with_integer_labels(logits, labels).mean()
            loss = loss + config.model.feature_transform_weight * pointnet.orthogonality_loss(transform)
            if head is not None:
                loss = loss + config.model.yaw_weight * yaw_loss(head, labels, yaw, class_orders)
            return loss, (logits, updates["batch_stats"])

        (loss, (logits, stats)), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params)
        state = state.apply_gradients(grads=grads).replace(batch_stats=stats)
        return state, {"loss": loss, "accuracy": jnp.mean(jnp.argmax(logits, -1) == labels)}

    @jax.jit
    def train_epoch(state: TrainState, bank: Bank, key: jax.Array):
        return jax.lax.scan(lambda s, k: step(s, k, bank), state, jax.random.split(key, steps))

    return train_epoch


def _classifier(state: TrainState, classes: tuple[str, ...], config: TrainConfig, orders: tuple[int, ...] = ()
                ) -> pointnet.Classifier:
    return pointnet.Classifier({"params": state.params, "batch_stats": state.batch_stats}, classes, config.model,
                               yaw_orders=orders if config.model.yaw_head else ())


def evaluation_sets(clouds: CloudSet, config: TrainConfig) -> dict[str, tuple[np.ndarray, ...]]:
    """Held-out clouds per source as (points [E, P, 3], mask [E, P], label [E], yaw [E] rad): a fixed subset
    of P points (clouds are stored in random order), complete clouds at ``eval_rotations`` evenly spaced
    yaws."""
    P = config.model.num_points
    sets = {}
    for i, source in enumerate(SOURCES):
        part = clouds.select(clouds.source == i)
        if not len(part):
            continue
        points, mask, label, yaw = part.points[:, :P], part.mask[:, :P], part.label, part.yaw
        if source == "full":
            yaws = 2 * np.pi * np.arange(config.eval_rotations) / config.eval_rotations
            R = np.asarray(geometry.yaw_rotation(yaws.astype(np.float32)))
            points = np.einsum("rij,cpj->rcpi", R, points).reshape(-1, P, 3)
            mask, label = np.tile(mask, (len(yaws), 1)), np.tile(label, len(yaws))
            yaw = (yaws[:, None] + yaw[None]).reshape(-1)
        sets[source] = (points.astype(np.float32), mask, label, yaw.astype(np.float32))
    return sets


def predict_all(classifier: pointnet.Classifier, points: np.ndarray, mask: np.ndarray, batch: int,
                fn=None) -> np.ndarray:
    """Predicted classes [E] of any number of clouds (or ``fn(classifier, points, mask)``'s output, default
    the argmax of ``classify``), in fixed-size batches (the last one padded with empty clouds) so that it
    compiles once."""
    fn = fn or (lambda c, p, m: jnp.argmax(pointnet.classify(c, p, m), -1))
    out = []
    for start in range(0, len(points), batch):
        p, m = points[start:start + batch], mask[start:start + batch]
        pad = batch - len(p)
        p, m = np.pad(p, ((0, pad), (0, 0), (0, 0))), np.pad(m, ((0, pad), (0, 0)))
        out.append(np.asarray(fn(classifier, p, m))[:batch - pad])
    return np.concatenate(out)


def held_out(classifier: pointnet.Classifier, evals: dict[str, tuple[np.ndarray, ...]], batch: int
             ) -> tuple[dict[str, float], dict[str, float]]:
    """Per source of ``evals`` (``evaluation_sets``): the accuracy and the mean negative log-likelihood of
    the true class (nats; it keeps falling after the accuracy saturates)."""
    accuracy, nll = {}, {}
    for source, (points, mask, label, _) in evals.items():
        probs = predict_all(classifier, points, mask, batch, pointnet.classify)
        accuracy[source] = float(np.mean(np.argmax(probs, -1) == label))
        nll[source] = float(-np.mean(np.log(np.maximum(probs[np.arange(len(label)), label], 1e-12))))
    return accuracy, nll


def yaw_errors(classifier: pointnet.Classifier, points: np.ndarray, mask: np.ndarray, label: np.ndarray,
               yaw: np.ndarray, batch: int) -> np.ndarray:
    """Degrees [E']: the yaw head's error for the true class of each cloud whose class has a finite order
    s, modulo 2 pi / s (a turn that maps the class onto itself is no error)."""
    estimate = predict_all(classifier, points, mask, batch, pointnet.estimate_yaw)[np.arange(len(label)), label]
    s = np.asarray(classifier.yaw_orders)[label]
    keep = s > 0
    period = 2 * np.pi / np.maximum(s, 1)
    wrapped = np.abs((estimate - yaw + period / 2) % period - period / 2)
    return np.degrees(wrapped[keep])


def _checkpoint_manager(run_dir: Path, config: TrainConfig) -> ocp.CheckpointManager:
    return ocp.CheckpointManager(run_dir.resolve() / "checkpoints",
                                 options=ocp.CheckpointManagerOptions(max_to_keep=config.keep_checkpoints))


def _saved(state: TrainState) -> dict:
    return {"params": state.params, "batch_stats": state.batch_stats, "opt_state": state.opt_state,
            "step": state.step}


def _resume_point(run_dir: Path, config: TrainConfig, classes: tuple[str, ...],
                  manager: ocp.CheckpointManager) -> int:
    """The epoch a run folder's checkpoints reached (0 for a new run), after checking that this config
    continues that run: the same settings (``epochs`` may grow) and the same class list."""
    start = manager.latest_step()
    if start is None:
        return 0
    saved_config = run_dir / "config.yaml"
    if saved_config.is_file():
        before = OmegaConf.to_container(OmegaConf.structured(load_config(TrainConfig, saved_config)))
        now = OmegaConf.to_container(OmegaConf.structured(config))
        # More epochs continue a halving run; a cosine run's rate at every step depends on its length.
        free = ("epochs",) if config.schedule is Schedule.halving else ()
        changed = sorted(k for k in set(before) | set(now) if k not in free and before.get(k) != now.get(k))
        if changed:
            raise ValueError(f"train: {run_dir} holds a run with other settings ({', '.join(changed)} differ "
                             f"from {saved_config}); resume with the same config or choose another out_dir")
    metrics_path = run_dir / "metrics.json"
    saved = json.loads(metrics_path.read_text())["classes"] if metrics_path.is_file() else None
    if saved is not None and tuple(saved) != classes:
        raise ValueError(f"train: {run_dir} holds a run on classes {saved}, but this config's object set has "
                         f"{list(classes)}; choose another out_dir")
    if start > config.epochs:
        raise ValueError(f"train: {run_dir} has trained {start} epochs already, more than epochs = {config.epochs}")
    return start


def train(config: TrainConfig, show_progress: bool = True) -> Path:
    """Run (or resume) a training; returns the run folder."""
    run_dir = Path(config.out_dir)
    devices = jax.devices()
    if config.batch_size % len(devices):
        raise ValueError(f"train: batch_size {config.batch_size} must be a multiple of the {len(devices)} devices")
    object_set = object_set_from_config(config.objects)
    # Without held-out instances (one model per class, as a BOP set such as LINEMOD has), evaluate on held-out
    # views and poses of the training instances: the test draw of the clouds, on the training models.
    evaluated_on = "test" if object_set.test else "train"
    if evaluated_on == "train":
        print(f"train: object set '{object_set.name}' has no held-out instances; evaluating on held-out views "
              "and poses of the training models", file=sys.stderr)
    classes = object_set.classes
    M = len(classes)
    manager = _checkpoint_manager(run_dir, config)
    start = _resume_point(run_dir, config, classes, manager)
    save_config(config, run_dir / "config.yaml")

    train_clouds = load_clouds(object_set, "train", config.data, config.objects, config.seed, show_progress,
                               config.perception)
    test_clouds = load_clouds(object_set, "test", config.data, config.objects, config.seed, show_progress,
                              config.perception, models_split=evaluated_on)
    used = np.asarray([getattr(config.mix, s) > 0 for s in SOURCES])[train_clouds.source]
    steps = config.steps_per_epoch or max(1, int(used.sum()) // config.batch_size)
    mesh = Mesh(np.asarray(devices), ("data",))
    replicated = NamedSharding(mesh, PartitionSpec())
    bank = jax.device_put(make_bank(train_clouds, config.mix), replicated)
    state = jax.device_put(create_state(config, M, steps), replicated)
    rate = learning_rate(config, steps)
    orders = pointnet.yaw_orders([[m.yaw_symmetry for m in object_set.train if m.class_name == c]
                                  for c in classes]) if config.model.yaw_head else ()
    train_epoch = make_train_epoch(config, M, steps, mesh, orders)
    evals = evaluation_sets(test_clouds, config)

    metrics_path = run_dir / "metrics.json"
    history: list[dict] = []
    if start:
        target = jax.tree.map(ocp.utils.to_shape_dtype_struct, _saved(state))
        state = state.replace(**manager.restore(start, args=ocp.args.StandardRestore(target)))
        if metrics_path.is_file():
            history = [h for h in json.loads(metrics_path.read_text())["history"] if h["epoch"] <= start]
    key = jax.random.key(config.seed + 1)

    bar = tqdm(range(start, config.epochs), desc=config.name, disable=not show_progress, initial=start,
               total=config.epochs)
    log = ScalarLog(run_dir / "tensorboard", resumed_at=start) if config.tensorboard else None
    for epoch in bar:
        began = time.perf_counter()
        state, per_step = train_epoch(state, bank, jax.random.fold_in(key, epoch))
        loss, accuracy = float(per_step["loss"].mean()), float(per_step["accuracy"].mean())
        if not math.isfinite(loss):  # diverged: keep the last good checkpoint, write nothing of this epoch
            raise RuntimeError(f"train: epoch {epoch + 1}: the loss is {loss}; the run diverged (lower "
                               f"learning_rate?). {run_dir} keeps epoch {epoch}: run again to resume from it")
        seconds = time.perf_counter() - began
        scores, test_loss = held_out(_classifier(state, classes, config, orders), evals, config.eval_batch)
        history.append({"epoch": epoch + 1, "loss": loss, "train_accuracy": accuracy, "test_accuracy": scores,
                        "test_loss": test_loss, "learning_rate": float(rate((epoch + 1) * steps - 1)),
                        "train_seconds": seconds, "clouds_per_second": steps * config.batch_size / seconds})
        io.write_json(metrics_path, {"classes": list(classes), "evaluated_on": EVALUATED_ON[evaluated_on],
                                     "history": history})
        if log is not None:
            log.write(epoch + 1, {k: v for k, v in history[-1].items() if k != "epoch"})
        manager.save(epoch + 1, args=ocp.args.StandardSave(_saved(state)))
        bar.set_postfix(loss=f"{loss:.3f}", acc=f"{accuracy:.3f}",
                        **{f"test_{s}": f"{v:.3f}" for s, v in scores.items()})
    manager.wait_until_finished()
    if log is not None:
        log.close()
    return finish(run_dir, config, classes, state, evals, history, orders, evaluated_on)


def finish(run_dir: Path, config: TrainConfig, classes: tuple[str, ...], state: TrainState,
           evals: dict, history: list[dict], orders: tuple[int, ...] = (), evaluated_on: str = "test") -> Path:
    """Final per-class figures (None for a class without held-out clouds), confusion matrices, the yaw
    head's errors, plots and the exported weights."""
    M = len(classes)
    classifier = _classifier(state, classes, config, orders)
    final: dict[str, Any] = {}
    for source, (p, m, y, yaw) in evals.items():
        predicted = predict_all(classifier, p, m, config.eval_batch)
        confusion = confusion_matrix(y, predicted, labels=np.arange(M))
        final[source] = {"accuracy": float(np.mean(predicted == y)), "count": len(y),
                         "per_class": {c: float(confusion[i, i] / confusion[i].sum()) if confusion[i].sum() else None
                                       for i, c in enumerate(classes)},
                         "confusion": confusion.tolist()}
        if config.model.yaw_head:
            errors = yaw_errors(classifier, p, m, y, yaw, config.eval_batch)
            final[source]["yaw_error_deg"] = {"median": float(np.median(errors)) if len(errors) else None,
                                              "within_15": float(np.mean(errors <= 15)) if len(errors) else None,
                                              "count": len(errors)}
    io.write_json(run_dir / "metrics.json", {"classes": list(classes), "evaluated_on": EVALUATED_ON[evaluated_on],
                                              "final": final, "history": history})
    viz.save(viz.training_curve(history), run_dir / "curve.png")
    viz.save(viz.confusion({s: np.asarray(f["confusion"]) for s, f in final.items()}, classes),
             run_dir / "confusion.png")
    pointnet.save_classifier(run_dir / "pointnet.msgpack", jax.device_get(classifier), {
        "object_set": config.objects.source, "trained_by": f"jaxcls train ({config.name})",
        "epochs": history[-1]["epoch"] if history else 0,
        "test_accuracy": {s: f["accuracy"] for s, f in final.items()}})
    return run_dir
