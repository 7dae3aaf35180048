"""A learned next-best-view policy: a small network that scores every candidate view of a move from what the
hand-made policies read (beyond the paper; issue 37).

Its input is the state the episode already has, as features of the move's K candidates (``nbv.candidates``) and
N segments (``features``):

- per (candidate, segment) pair [K, N, P] (P: ``Layout.pair_features``): the pixels of the segment's aligned model
  cuboid the candidate would see through the z-buffer (Eq. 5, ``visibility`` "paper" mode), over the most any
  pair sees and over the most that segment shows at any candidate; the segment's uncertainty
  (``nbv.uncertainty``: 1 - the margin of its best rho over the second) and that uncertainty times the second
  count. Layout 3 adds where the candidate camera is seen from the segment, as a unit vector in its aligned
  model's frame (from the cuboid's centre: which side of the model the view would show), the model cuboid's size
  (dm) and the segment's best and second-best rho (Eq. 2): what tells which view can settle a class, for any
  object set (no class count in the layout);
- per candidate [K, CANDIDATE_FEATURES]: the history weight (Eq. 6), the distance from the current view over the
  radius, within the radius, visited, the cosine between its optical axis and the current one's, how far down
  it looks (minus its axis' z), the paper's VisOcclHist utility (Eq. 7, ``VIS_OCCL_HIST``), the views fused so far
  over 10, and InfoGain's utility (``INFO_GAIN``: the TSDF's unobserved voxels the view reaches, normalised over
  the candidates, times the history weight; ``nbv.InfoGain``).

The network (``ViewScorer``) is permutation-invariant over the segments (a shared MLP on each pair, then the
mean and max over the live segments) and scores each candidate with a second shared MLP: any K and N, the same
weights. Its score is a linear term of the candidate features (``skip``) plus the MLP's: ``init(key, hidden,
base)`` starts it as a hand-made policy exactly (``skip`` one-hot on that utility, the MLP's last layer zero),
so training (``experiments/policy``) corrects the best hand-made policy where the oracle sees a better view
instead of learning it again. ``scores`` is the policy's utility; ``nbv.Learned`` takes its best candidate
within the radius (Eq. 8).

Weights are a ``.msgpack`` and a ``.json`` beside it (``save``, ``load``): the width, the feature layout
(``Layout``) and the candidate count the policy was trained with; ``load`` refuses weights of other shapes, a
layout it does not read or another candidate count, naming the file and what differs. A network's layout is
its first layer's input size (``Layout.of``), so weights of either layout run in the same episode code.
"""

from __future__ import annotations

import dataclasses
import enum
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import linen as nn
from flax import serialization, struct

from jaxcls import io
from jaxcls.geometry import Intrinsics, rotate
from jaxcls.math import safe_div
from jaxcls.planning import nbv, visibility

CANDIDATE_FEATURES = 9
VIS_OCCL_HIST = 6  # the candidate feature that is the paper's VisOcclHist utility (Eq. 7)
INFO_GAIN = 8  # the candidate feature that is InfoGain's utility
KIND = "jaxcls view policy"
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
# name -> shipped .msgpack (RESULTS.md, "The learned view policy"): ``jaxcls train-policy --config policy_NAME``;
# real_like for the shipped classifier; for the paper-recipe one real_like_paper and synthetic_paper (imitation of
# rollout labels), real_like_paper_ppo and synthetic_paper_ppo (PPO from those two), real_like_paper_ppo_scenes256
# (PPO from real_like_paper_ppo on 4x the training scenes), all on layout 2; on layout 3 real_like_paper_v3
# (imitation with early stopping, then PPO) and real_like_paper_v3_scenes256 (PPO from it on 256 scenes: the highest
# F1 on the real-like set, a tie with real_like_paper_ppo_scenes256).
SHIPPED_WEIGHTS: dict[str, Path] = {name: WEIGHTS_DIR / f"learned_{name}.msgpack"
                                    for name in ("real_like", "real_like_paper", "synthetic_paper",
                                                 "real_like_paper_ppo", "synthetic_paper_ppo",
                                                 "real_like_paper_ppo_scenes256", "real_like_paper_v3",
                                                 "real_like_paper_v3_scenes256")}


class Layout(enum.IntEnum):
    """The network's input (``features``; the module docstring), by its number in a weights file's ``.json``.
    Layout 1 (no InfoGain feature, no skip term) is no longer read; 2 and 3 are, each policy by its own."""

    v2 = 2  # the pair's 4: the cuboid's visible pixels (two normalisations), the uncertainty, their product
    v3 = 3  # v2's, where the candidate is seen from in the segment's model frame (3), the model's size (3), rho's top 2

    @property
    def pair_features(self) -> int:
        """P, the features of a (candidate, segment) pair."""
        return {Layout.v2: 4, Layout.v3: 12}[self]

    @classmethod
    def of(cls, weights: dict) -> Layout:
        """The layout a network's weights read: its first layer's input size (static under jit)."""
        size = int(weights["params"]["pair_0"]["kernel"].shape[0])
        for layout in cls:
            if layout.pair_features == size:
                return layout
        raise ValueError(f"learned: a network whose first layer takes {size} pair features is of no layout "
                         f"({ {layout.value: layout.pair_features for layout in cls} })")


class Base(enum.Enum):
    """The hand-made policy a fresh network scores exactly (``init``): its utility's candidate feature."""

    none = "none"  # a random network
    vis_occl_hist = "vis_occl_hist"
    info_gain = "info_gain"

    @property
    def feature(self) -> int | None:
        """The candidate feature holding this policy's utility (None: none)."""
        return {Base.vis_occl_hist: VIS_OCCL_HIST, Base.info_gain: INFO_GAIN}.get(self)


class Features(struct.PyTreeNode):
    """A move's input to the network: pair [K, N, P] (``Layout.pair_features``), live [N] bool, candidate [K,
    CANDIDATE_FEATURES] (see the module docstring)."""

    pair: jax.Array
    live: jax.Array
    candidate: jax.Array


def features(views: nbv.Views, belief: nbv.Belief, index: jax.Array, ok: jax.Array, intrinsics: Intrinsics,
             config: nbv.NBVConfig, layout: Layout = Layout.v2) -> Features:
    """The network's input in ``layout`` for the candidates ``index`` [K] (``ok`` [K]: within the radius) of a move
    whose planner sees ``views`` and ``belief`` (its ``volume``, the fused TSDF, is needed: InfoGain's feature;
    layout 3 needs its ``rho``). Pure; finite for any state (no live segment, nothing visible, nothing left
    unobserved); a dead segment's pair features are 0."""
    layout = Layout(layout)
    if belief.volume is None:
        raise ValueError("learned.features: the learned policy needs Belief.volume (the fused TSDF) for InfoGain's "
                         "feature")
    if layout is Layout.v3 and belief.rho is None:
        raise ValueError("learned.features: layout 3 needs Belief.rho (each segment's rho per candidate class)")
    paper = dataclasses.replace(config.visibility, mode=visibility.Mode.paper)
    counts = visibility.counts(belief.corners, belief.poses, belief.live, views.T_wc[index], intrinsics, paper)
    counts = jnp.where(belief.live[None, :], counts, 0.0)  # [K, N]
    by_all = safe_div(counts, jnp.max(counts))
    by_segment = safe_div(counts, jnp.max(counts, axis=0, keepdims=True))
    unsure = (jnp.zeros(belief.live.shape, jnp.float32) if belief.uncertainty is None
              else jnp.where(belief.live, belief.uncertainty, 0.0))
    unsure = jnp.broadcast_to(unsure[None, :], counts.shape)
    pair = jnp.stack([by_all, by_segment, unsure, unsure * by_segment], axis=-1)
    if layout is Layout.v3:
        pair = jnp.concatenate([pair, _seen_from(views.T_wc[index], belief)], axis=-1)

    weight = nbv.history_weight(views, index, config)
    total = jnp.sum(counts, axis=1)
    utility = jnp.where(jnp.max(total) > 0, weight * safe_div(total, jnp.max(total)), weight)  # Eq. 7
    position, axis = views.T_wc[:, :3, 3], views.T_wc[:, :3, 2]
    distance = jnp.linalg.norm(position[index] - position[views.current], axis=-1) / config.radius
    facing = jnp.sum(axis[index] * axis[views.current], axis=-1)
    fused = jnp.broadcast_to(jnp.sum(views.visited).astype(jnp.float32) / 10.0, index.shape)
    gain = config.info_gain.utilities(views, belief, index, intrinsics, config)  # (normalised, times the weight)
    candidate = jnp.stack([weight, distance, ok.astype(jnp.float32), views.visited[index].astype(jnp.float32),
                           facing, -axis[index, 2], utility, fused, gain], axis=-1)
    return Features(pair=pair.astype(jnp.float32), live=belief.live, candidate=candidate.astype(jnp.float32))


def _seen_from(T_wc: jax.Array, belief: nbv.Belief) -> jax.Array:
    """Layout 3's pair features [K, N, 8] of cameras T_wc [K, 4, 4] and the belief's N segments: the unit vector
    from the segment's cuboid centre to the camera in its aligned model's frame (3; invariant to moving the whole
    scene rigidly), the cuboid's size along the model's axes in dm (3), its best and second rho (2); 0 for a dead
    segment."""
    rotation, translation = belief.poses[:, :3, :3], belief.poses[:, :3, 3]  # [N, 3, 3], [N, 3]
    centre = jnp.mean(belief.corners, axis=1)  # [N, 3] (model frame)
    offset = T_wc[:, None, :3, 3] - translation[None]  # [K, N, 3] world
    to_model = jax.vmap(lambda R, x: rotate(R.T, x), in_axes=(0, 1), out_axes=1)  # (full float32)
    local = to_model(rotation, offset) - centre[None]  # R^T (p - t) - c
    length = jnp.linalg.norm(local, axis=-1, keepdims=True)
    direction = jnp.where(length > 1e-9, local / jnp.maximum(length, 1e-9), 0.0)
    size = (jnp.max(belief.corners, axis=1) - jnp.min(belief.corners, axis=1)) / 0.1  # [N, 3] dm
    top = jax.lax.top_k(belief.rho, min(2, belief.rho.shape[1]))[0]
    top = jnp.pad(top, ((0, 0), (0, 2 - top.shape[1])))  # [N, 2] (a single candidate class: second 0)
    segment = jnp.broadcast_to(jnp.concatenate([size, top], axis=-1)[None], (*direction.shape[:2], 5))
    out = jnp.concatenate([direction, segment], axis=-1)
    return jnp.where(belief.live[None, :, None], out, 0.0)


class ViewScorer(nn.Module):
    """[K] a score per candidate from ``Features`` (one move; vmap for several)."""

    hidden: int = 64

    @nn.compact
    def __call__(self, x: Features) -> jax.Array:
        h = nn.relu(nn.Dense(self.hidden, name="pair_0")(x.pair))
        h = nn.relu(nn.Dense(self.hidden, name="pair_1")(h))  # [K, N, H]
        live = x.live[None, :, None]
        count = jnp.maximum(jnp.sum(x.live), 1).astype(h.dtype)
        mean = jnp.sum(jnp.where(live, h, 0.0), axis=1) / count
        peak = jnp.where(jnp.any(x.live), jnp.max(jnp.where(live, h, -jnp.inf), axis=1), 0.0)  # (h >= 0)
        c = jnp.concatenate([mean, peak, x.candidate], axis=-1)
        c = nn.relu(nn.Dense(self.hidden, name="candidate_0")(c))
        c = nn.relu(nn.Dense(self.hidden, name="candidate_1")(c))
        return (nn.Dense(1, name="score")(c) + nn.Dense(1, use_bias=False, name="skip")(x.candidate))[..., 0]


def init(key: jax.Array, hidden: int, base: Base | str = Base.none, layout: Layout | int = Layout.v2) -> dict:
    """Fresh weights of a ``ViewScorer`` of width ``hidden`` (any K, N) reading features of ``layout``. ``base``
    (``Base``): none, random throughout; else the network scores exactly that hand-made utility (``skip`` one-hot
    on it, the MLP's ``score`` layer zero: its hidden layers random, so their gradients are not)."""
    try:
        base = Base(base)
    except ValueError:
        raise ValueError(f"learned.init: base {base!r} is not one of {[b.value for b in Base]}") from None
    example = Features(pair=jnp.zeros((2, 3, Layout(layout).pair_features)), live=jnp.ones(3, bool),
                       candidate=jnp.zeros((2, CANDIDATE_FEATURES)))
    weights = ViewScorer(hidden).init(key, example)
    if base.feature is None:
        return weights
    params = dict(weights["params"])
    params["score"] = jax.tree.map(jnp.zeros_like, params["score"])
    params["skip"] = {"kernel": jnp.zeros((CANDIDATE_FEATURES, 1)).at[base.feature, 0].set(1.0)}
    return {**weights, "params": params}


def apply(weights: dict, x: Features) -> jax.Array:
    """[..., K] the network's scores of ``x`` (leading axes: moves, vmapped); the width is the weights'."""
    if x.candidate.ndim > 2:
        return jax.vmap(lambda one: apply(weights, one))(x)
    return ViewScorer(int(weights["params"]["pair_0"]["kernel"].shape[-1])).apply(weights, x)


def scores(weights: dict, views: nbv.Views, belief: nbv.Belief, index: jax.Array, ok: jax.Array,
           intrinsics: Intrinsics, config: nbv.NBVConfig) -> jax.Array:
    """[K] the learned policy's utility of the candidates ``index`` (``features`` in the weights' layout, then
    ``ViewScorer``)."""
    return apply(weights, features(views, belief, index, ok, intrinsics, config, Layout.of(weights)))


@dataclasses.dataclass(frozen=True)
class Info:
    """What a weights file says of itself (its ``.json``): the width, the feature layout, the candidate count
    it was trained with, and free ``metadata`` (the training's figures)."""

    hidden: int
    max_candidates: int
    features: Layout = Layout.v2
    metadata: dict = dataclasses.field(default_factory=dict)


def save(path: str | Path, weights: dict, max_candidates: int, metadata: dict | None = None) -> Path:
    """Write ``weights`` as a ``.msgpack`` (float32) and a ``.json`` beside it (``Info``), each atomically."""
    path = Path(path)
    stored = jax.tree.map(lambda a: np.asarray(a, np.float32), jax.device_get(weights))
    if not all(np.all(np.isfinite(a)) for a in jax.tree.leaves(stored)):
        raise ValueError("learned policy: the weights are not finite; nothing written")
    hidden = int(stored["params"]["pair_0"]["kernel"].shape[-1])
    layout = Layout.of(stored)
    io.write_bytes(path, serialization.msgpack_serialize(serialization.to_state_dict(stored)))
    io.write_json(path.with_suffix(".json"), {"kind": KIND, "hidden": hidden, "features": layout.value,
                                              "max_candidates": int(max_candidates), **(metadata or {})}, indent=2)
    return path


def weights_file(path: str | Path) -> Path:
    """The ``.msgpack`` a policy's weights are in: a shipped name's (``SHIPPED_WEIGHTS``), else ``path``."""
    return Path(SHIPPED_WEIGHTS.get(str(path), path))


def load(path: str | Path, max_candidates: int) -> tuple[dict, Info]:
    """The weights at ``path`` (a shipped name of ``SHIPPED_WEIGHTS``, or a ``.msgpack`` with its ``.json``) for
    a planner of ``max_candidates`` candidates, on the default device, and their ``Info``. ValueError naming the
    file where they are not a view policy's, of another feature layout, other shapes or another candidate count."""
    path = weights_file(path)
    info_path = path.with_suffix(".json")
    for p in (path, info_path):
        if not p.is_file():
            raise FileNotFoundError(f"learned policy: {p} not found (weights come as a .msgpack and a .json, "
                                    "written by jaxcls train-policy)")
    try:
        info = json.loads(info_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{info_path}: not valid JSON ({e})") from None
    if not isinstance(info, dict) or info.get("kind") != KIND:
        raise ValueError(f"{info_path}: not a view policy's weights (expected 'kind': {KIND!r})")
    for key in ("hidden", "features", "max_candidates"):
        if isinstance(info.get(key), bool) or not isinstance(info.get(key), int) or info[key] < 1:
            raise ValueError(f"{info_path}: {key!r} must be a positive integer, got {info.get(key)!r}")
    if info["features"] not in {layout.value for layout in Layout}:
        raise ValueError(f"{info_path}: weights of feature layout {info['features']}, this jaxcls reads layouts "
                         f"{[layout.value for layout in Layout]}: train them again (jaxcls train-policy)")
    if info["max_candidates"] != max_candidates:
        raise ValueError(f"{info_path}: weights trained with {info['max_candidates']} candidates a move, the planner "
                         f"has nbv.max_candidates = {max_candidates}")
    template = jax.eval_shape(lambda: init(jax.random.key(0), info["hidden"], layout=info["features"]))
    weights = io.read_weights(path, template, "learned policy",
                              f"a view policy of width {info['hidden']} ({info_path.name})")
    metadata = {k: v for k, v in info.items() if k not in ("kind", "hidden", "features", "max_candidates")}
    return (jax.device_put(jax.tree.map(lambda a: np.asarray(a, np.float32), weights)),
            Info(info["hidden"], info["max_candidates"], Layout(info["features"]), metadata))


__all__ = ["CANDIDATE_FEATURES", "Base", "Features", "Info", "Layout", "ViewScorer", "apply", "features", "init",
           "load", "save", "scores"]
