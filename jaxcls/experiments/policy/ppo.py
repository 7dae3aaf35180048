"""Reinforcement learning of the view policy after its imitation of the oracle: PPO (clipped surrogate, GAE, a
critic), PureJaxRL-style. One update is one jitted program: E episodes rolled out on frames in memory (vmapped,
a ``lax.scan`` over the moves, each move the whole perception step), then ``epochs`` passes of shuffled
minibatches over their decisions.

The actor is the learned policy's network (``learned.ViewScorer``): a softmax over its scores of the allowed
candidates (``nbv.unvisited_first``), sampled while training; the critic a second ``ViewScorer`` whose scores are
averaged over the allowed candidates (a value of the state). The reward of a move is the gain in the target objects'
macro F1 of the refined labels (``scoring.target_f1``, the oracle's score), so an episode's return is its last move's
F1 minus its first's; episodes are undiscounted (``gamma`` 1 by default). A decision's advantage is GAE over the
critic's values, or, with ``group`` > 1, its return-to-go less that of the other episodes of its group at the same
decision (``group_advantages``).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from jaxcls.config import bounded, check_bounds
from jaxcls.episode import active, scoring
from jaxcls.planning import learned, nbv


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """The ``ppo:`` block of ``PolicyConfig``: after the imitation rounds, ``updates`` PPO updates (0: none), each
    on ``runs`` episodes of every one of the ``train_scenes`` training scenes whose frames are in memory.

    With ``new_scenes`` > 0 those scenes are a window that slides along the training draw: update u (from 0) sees
    scenes [u * new_scenes, u * new_scenes + train_scenes), the ``new_scenes`` it has not seen rendered in place
    of the oldest before it runs. Every update then rolls out as many episodes as before, and a run of U updates
    sees train_scenes + (U - 1) * new_scenes scenes, each in about train_scenes / new_scenes updates. 0: the same
    scenes every update.

    ``rollout_batch`` > 0 rolls an update's episodes out in groups of that many, one group after the other
    (``lax.map``), so the rollout's memory is a group's, not every episode's: more episodes an update than fit on
    the device at once, at the same figures. 0: all at once (``vmap``).

    ``group`` > 1 rolls each run (a scene and its start) out ``group`` times. The episodes of a group share frames
    and start, and perception is deterministic given the views, so their returns differ only by the actor's
    samples. A decision's advantage is then its return-to-go less the mean of the group's other episodes' at the
    same decision (a leave-one-out baseline, ``group_advantages``), not GAE over the critic's values: the baseline
    knows the scene's and start's difficulty, which the critic must learn from the features. (The critic is still
    fitted, and unused.) An update rolls out train_scenes x runs x group episodes."""

    updates: int = bounded(0, ge=0)
    new_scenes: int = bounded(0, ge=0)  # training scenes replaced before each update (at most train_scenes)
    epochs: int = bounded(4, ge=1)  # passes over an update's decisions
    minibatches: int = bounded(4, ge=1)
    learning_rate: float = bounded(1e-4, gt=0.0)
    clip: float = bounded(0.2, gt=0.0)
    gamma: float = bounded(1.0, ge=0.0, le=1.0)
    gae_lambda: float = bounded(0.95, ge=0.0, le=1.0)
    value_coef: float = bounded(0.5, ge=0.0)
    entropy_coef: float = bounded(0.01, ge=0.0)
    temperature: float = bounded(1.0, gt=0.0)  # the actor's softmax is over its scores / temperature (< 1: greedier)
    max_grad_norm: float = bounded(0.5, gt=0.0)
    eval_every: int = bounded(10, ge=1)  # updates between held-out evaluations (and the last)
    rollout_batch: int = bounded(0, ge=0)  # episodes rolled out at once (0: all; else groups of it under lax.map)
    group: int = bounded(1, ge=1)  # episodes of each run (scene and start); > 1: the group's leave-one-out baseline

    def __post_init__(self) -> None:
        check_bounds(self, "ppo.")


class Decided(struct.PyTreeNode):
    """What a rollout keeps of each decision (after the first move), [E, T - 1] leading axes: the network's input,
    the allowed candidates, the candidate taken, its log-probability, the critic's value, the reward (F1 gain)."""

    features: learned.Features
    allowed: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    reward: jax.Array


def logits(actor: dict, x: learned.Features, allowed: jax.Array, temperature: float = 1.0) -> jax.Array:
    """The actor's logits [..., C]: its scores of the candidates / ``temperature``, -1e9 where not ``allowed``."""
    return jnp.where(allowed, learned.apply(actor, x) / temperature, -1e9)


def _value(critic: dict, x: learned.Features, allowed: jax.Array) -> jax.Array:
    scores = learned.apply(critic, x)
    return jnp.sum(jnp.where(allowed, scores, 0.0), axis=-1) / jnp.maximum(jnp.sum(allowed, axis=-1), 1)


def _f1(truth: scoring.TruthArrays, state: active.EpisodeState, classes: int) -> jax.Array:
    r = state.refinement
    return scoring.target_f1(truth, active.centroids(state.observation), r.valid, r.refined, classes)


def rollout(params: dict, episode: active.Episode, depth: jax.Array, T_wc: jax.Array, scene: jax.Array,
            start: jax.Array, keys: jax.Array, truths: scoring.TruthArrays, sample: bool = True,
            temperature: float = 1.0, batch: int = 0) -> tuple[Decided, jax.Array]:
    """E episodes (scene [E], start [E], keys [E], truths [E] leaves) on the frames depth [S, V, H, W], T_wc [S, V,
    4, 4], each decision after the first move the actor's (sampled from ``logits`` at ``temperature``, or its best
    with ``sample`` False): the [E, T - 1] decisions and [E] each episode's last F1. ``batch`` > 0: the episodes
    in groups of ``batch`` (``lax.map``; the last group the remainder), else all at once."""
    classes = len(episode.spec.classifier.classes)
    config = episode.nbv_config
    layout = learned.Layout.of(params["actor"])  # (the critic reads the same features)

    def one(s, first, key, truth):
        key, reset_key = jax.random.split(key)
        state = active.reset(episode, T_wc[s], first, reset_key)
        state = active.step(episode, state, depth[s, first], T_wc[s, first])

        def move(carry, key):
            state, before = carry
            views = active.planned_views(state)
            index, ok = nbv.candidates(views, config)
            allowed = nbv.unvisited_first(state.views, index, ok)
            x = learned.features(views, active.belief(episode, state), index, ok, episode.spec.intrinsics, config,
                                 layout)
            scores = logits(params["actor"], x, allowed, temperature)
            action = jax.random.categorical(key, scores) if sample else jnp.argmax(scores)
            view = index[action]
            state = active.step(episode, state.replace(next_view=view, next_pose=state.views.T_wc[view]),
                                depth[s, view], T_wc[s, view])
            after = _f1(truth, state, classes)
            log_prob = jax.nn.log_softmax(scores)[action]
            return (state, after), Decided(x, allowed, action, log_prob, _value(params["critic"], x, allowed),
                                           after - before)

        (state, last), decided = jax.lax.scan(move, (state, _f1(truth, state, classes)),
                                              jax.random.split(key, episode.config.moves - 1))
        return decided, last

    if 0 < batch < start.shape[0]:
        return jax.lax.map(lambda args: one(*args), (scene, start, keys, truths), batch_size=batch)
    return jax.vmap(one)(scene, start, keys, truths)


def advantages(reward: jax.Array, value: jax.Array, gamma: float, lam: float) -> tuple[jax.Array, jax.Array]:
    """(advantages, returns) [E, D] by GAE(gamma, lambda) of the rewards and values [E, D] of E episodes' D
    decisions; an episode ends after its last decision (no value after it)."""
    def one(r, v):
        def back(carry, rv):
            gae, next_value = carry
            delta = rv[0] + gamma * next_value - rv[1]
            gae = delta + gamma * lam * gae
            return (gae, rv[1]), gae

        return jax.lax.scan(back, (jnp.zeros((), r.dtype), jnp.zeros((), r.dtype)), (r, v), reverse=True)[1]

    adv = jax.vmap(one)(reward, value)
    return adv, adv + value


def group_advantages(reward: jax.Array, group: int, gamma: float) -> tuple[jax.Array, jax.Array]:
    """(advantages, returns) [E, D] of E episodes' D decisions, the episodes in consecutive groups of ``group`` that
    share a scene and start: a decision's return-to-go (discounted by ``gamma``) less the mean of the return-to-go
    of the group's other ``group - 1`` episodes at the same decision. The baseline does not depend on the episode's
    own choices, so the advantage is unbiased; a group's advantages at a decision sum to 0."""
    E, D = reward.shape
    if group < 2 or E % group:
        raise ValueError(f"ppo.group: {E} episodes do not make groups of {group} (at least 2 episodes a group)")
    to_go, _ = advantages(reward, jnp.zeros_like(reward), gamma, 1.0)  # (GAE with lambda 1 and no critic)
    per = to_go.reshape(E // group, group, D)
    others = (per.sum(axis=1, keepdims=True) - per) / (group - 1)
    return (per - others).reshape(E, D), to_go


def loss(params: dict, batch: Decided, adv: jax.Array, returns: jax.Array, config: PPOConfig
         ) -> tuple[jax.Array, dict[str, jax.Array]]:
    """PPO's loss of a minibatch ([B] leading axes): the clipped surrogate, the value's squared error, the entropy."""
    log_p = jax.nn.log_softmax(logits(params["actor"], batch.features, batch.allowed, config.temperature))
    new = jnp.take_along_axis(log_p, batch.action[:, None], axis=-1)[:, 0]
    ratio = jnp.exp(new - batch.log_prob)
    norm = (adv - adv.mean()) / (adv.std() + 1e-8)
    surrogate = -jnp.mean(jnp.minimum(ratio * norm, jnp.clip(ratio, 1 - config.clip, 1 + config.clip) * norm))
    value = jnp.mean((_value(params["critic"], batch.features, batch.allowed) - returns) ** 2)
    entropy = -jnp.mean(jnp.sum(jnp.where(batch.allowed, jnp.exp(log_p) * log_p, 0.0), axis=-1))
    total = surrogate + config.value_coef * value - config.entropy_coef * entropy
    return total, {"surrogate": surrogate, "value": value, "entropy": entropy}


def optimizer(config: PPOConfig) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(config.max_grad_norm), optax.adam(config.learning_rate))


@functools.partial(jax.jit, static_argnames=("config",))
def update(params: dict, opt_state: Any, episode: active.Episode, depth: jax.Array, T_wc: jax.Array,
           scene: jax.Array, start: jax.Array, truths: scoring.TruthArrays, key: jax.Array, config: PPOConfig
           ) -> tuple[dict, Any, dict[str, jax.Array]]:
    """One PPO update in one program: the rollout of E episodes (scene, start [E]; ``truths`` [E] leaves; with
    ``config.group`` > 1 in consecutive groups of that many of one scene and start), the advantages,
    ``epochs`` passes of ``minibatches`` shuffled minibatches. Returns the new parameters (``{"actor", "critic"}``)
    and optimiser state and the update's figures (the rollout's mean last F1 and return, the mean absolute advantage
    before a minibatch normalises it, the last pass's losses)."""
    roll_key, shuffle_key = jax.random.split(key)
    decided, last = rollout(params, episode, depth, T_wc, scene, start, jax.random.split(roll_key, start.shape[0]),
                            truths, temperature=config.temperature, batch=config.rollout_batch)
    if config.group > 1:
        adv, returns = group_advantages(decided.reward, config.group, config.gamma)
    else:
        adv, returns = advantages(decided.reward, decided.value, config.gamma, config.gae_lambda)
    flat = jax.tree.map(lambda a: a.reshape(-1, *a.shape[2:]), (decided, adv, returns))
    size = flat[1].shape[0]
    per = size // config.minibatches
    if per < 1:
        raise ValueError(f"ppo: {size} decisions an update ({start.shape[0]} episodes x {episode.config.moves - 1} "
                         f"after the first move) cannot fill ppo.minibatches = {config.minibatches}")
    opt = optimizer(config)

    def epoch(carry, key):
        params, opt_state = carry
        order = jax.random.permutation(key, size)[:per * config.minibatches].reshape(config.minibatches, per)

        def minibatch(carry, rows):
            params, opt_state = carry
            part = jax.tree.map(lambda a: a[rows], flat)
            (_, figures), grads = jax.value_and_grad(loss, has_aux=True)(params, *part, config)
            updates, opt_state = opt.update(grads, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state), figures

        return jax.lax.scan(minibatch, (params, opt_state), order)

    (params, opt_state), figures = jax.lax.scan(epoch, (params, opt_state),
                                                jax.random.split(shuffle_key, config.epochs))
    out = {k: v[-1].mean() for k, v in figures.items()}
    return params, opt_state, {"f1_last": last.mean(), "reward": decided.reward.sum(axis=1).mean(),
                               "advantage": jnp.abs(adv).mean(), **out}


__all__ = ["Decided", "PPOConfig", "advantages", "group_advantages", "logits", "loss", "optimizer", "rollout", "update"]
