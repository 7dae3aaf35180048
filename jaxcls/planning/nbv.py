"""Next-best-view (paper Sec. 3.3, Eq. 5-8): score the candidate views of a move and pick one.

The candidates of a move are the viewpoints within ``radius`` of the current one (the paper's r = 0.5 m),
at most ``max_candidates`` of them, nearest first (a static shape). Visited ones stay candidates but the
history weight lowers them (Eq. 6); ``random`` draws among the unvisited ones only.

    O_i = sum_j O_i^j                    (Eq. 5: visible pixels of segment j's aligned cuboid at view i)
    W_i = 1 - G(min_tau D(i, tau))       (Eq. 6, G(d) = exp(-d^2 / 2 sigma^2), sigma = r / 2; "min" over the
                                          visited views as DESIGN.md explains; ``history="max"`` is the
                                          paper's literal max over tau of 1 - G, for the ablation)
    U_i = W_i * O_i / max_i O_i          (Eq. 7)
    next view = argmax_i U_i             (Eq. 8)

Policies are typed configs in a registry (``POLICIES``: name -> config class), each run by ``choose``, a
pure function ``(config, views, belief, key) -> view index``:

- ``random``: a uniformly random unvisited candidate;
- ``vis_no_occl``: Eq. 7 without the z-buffer (each cuboid counted alone) and without history;
- ``vis_occl``: with the z-buffer (``visibility`` "paper" mode), without history;
- ``vis_occl_hist``: with both (the paper's VisOcclHist);
- ``vis_occl_hist_unc`` (beyond the paper): VisOcclHist with each segment's pixels weighted by its
  ``uncertainty`` (by default 1 - the margin of its best rho over the second);
- ``info_gain`` (beyond the paper): the unobserved voxels of the TSDF a view would reach, times the history
  weight;
- ``continuous`` (beyond the paper): gradient ascent of the soft utility over the view sphere from the best
  candidates, snapped to the nearest viewpoint;
- ``learned`` (beyond the paper): a network's score of each candidate (``planning.learned``), its weights
  traced in the belief (``Belief.weights``).

Documented choices for degenerate inputs (never NaN, never a crash inside jit): no live segment or nothing
visible at any candidate -> O is 0 everywhere: the history policies take U = W (the least visited direction),
the others the nearest candidate (ties go to the nearest); no candidate within the radius -> the nearest
other viewpoint; ``random`` with every candidate
visited -> the nearest unvisited viewpoint, or a random candidate when every viewpoint is visited.
"""

from __future__ import annotations

import dataclasses
import enum
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxcls import geometry
from jaxcls.config import bounded, check_bounds
from jaxcls.geometry import Intrinsics
from jaxcls.math import safe_div
from jaxcls.perception.tsdf import TSDFVolume
from jaxcls.planning import information, visibility


class PolicyName(enum.StrEnum):
    """The registered policies (``episode.policy``; ``POLICIES`` maps each to its config class)."""

    random = "random"
    vis_no_occl = "vis_no_occl"
    vis_occl = "vis_occl"
    vis_occl_hist = "vis_occl_hist"
    vis_occl_hist_unc = "vis_occl_hist_unc"
    info_gain = "info_gain"
    continuous = "continuous"
    learned = "learned"


class History(enum.StrEnum):
    """Eq. 6 over the visited views: the ``min`` distance decides (the paper's intent, DESIGN.md) or the
    literal ``max`` over the visited views of 1 - G (the ablation)."""

    min = "min"
    max = "max"


class Uncertainty(enum.StrEnum):
    """What ``uncertainty`` measures (see there)."""

    rho_margin = "rho_margin"
    entropy = "entropy"
    one_minus_rho = "one_minus_rho"


@dataclasses.dataclass(frozen=True)
class Random:
    """The paper's Random: a uniformly random unvisited candidate."""

    name: ClassVar[PolicyName] = PolicyName.random

    def choose(self, views: Views, belief: Belief, key: jax.Array, intrinsics: Intrinsics,
               config: NBVConfig) -> jax.Array:
        index, ok = candidates(views, config)
        position = views.T_wc[:, :3, 3]
        fresh = ok & ~views.visited[index]
        draw = jax.random.uniform(key, index.shape)
        pick = index[jnp.argmax(jnp.where(fresh, draw, -1.0))]
        d = jnp.linalg.norm(position - position[views.current], axis=-1)
        unvisited = jnp.where(views.visited, jnp.inf, d)
        fallback = jnp.where(jnp.isfinite(jnp.min(unvisited)), jnp.argmin(unvisited),
                             index[jnp.argmax(jnp.where(ok, draw, -1.0))])
        return jnp.where(jnp.any(fresh), pick, jnp.where(jnp.any(ok), fallback, index[0])).astype(jnp.int32)


def _visible(belief: Belief, views: Views, index: jax.Array, intrinsics: Intrinsics, config: NBVConfig,
             mode: visibility.Mode) -> jax.Array:
    """[K, N] Eq. 5's visible pixels of each live cuboid at the viewpoints ``index`` [K]."""
    return visibility.counts(belief.corners, belief.poses, belief.live, views.T_wc[index], intrinsics,
                             dataclasses.replace(config.visibility, mode=mode))


def _argmax_candidate(U: jax.Array, index: jax.Array, ok: jax.Array) -> jax.Array:
    """[] i32 Eq. 8 over the candidates within the radius (ties: the nearest, ``index`` is sorted); none
    within it: the nearest other viewpoint."""
    best = index[jnp.argmax(jnp.where(ok, U, -jnp.inf))]
    return jnp.where(jnp.any(ok), best, index[0]).astype(jnp.int32)


def _with_history(total: jax.Array, views: Views, index: jax.Array, config: NBVConfig) -> jax.Array:
    """[K] Eq. 7: the history weight times ``total`` [K] normalised by its maximum; U = W where nothing
    counts anywhere."""
    weight = history_weight(views, index, config)
    return jnp.where(jnp.max(total) > 0, weight * safe_div(total, jnp.max(total)), weight)


class _ScoresCandidates:
    """A policy that scores every candidate (``utilities``: [K] Eq. 7, or its own utility) and takes the
    best (Eq. 8)."""

    def utilities(self, views: Views, belief: Belief, index: jax.Array, intrinsics: Intrinsics,
                  config: NBVConfig) -> jax.Array:
        raise NotImplementedError

    def choose(self, views: Views, belief: Belief, key: jax.Array, intrinsics: Intrinsics,
               config: NBVConfig) -> jax.Array:
        index, ok = candidates(views, config)
        return _argmax_candidate(self.utilities(views, belief, index, intrinsics, config), index, ok)


@dataclasses.dataclass(frozen=True)
class VisNoOccl(_ScoresCandidates):
    """The paper's VisNoOccl: visibility without occlusion (each cuboid counted alone), no history."""

    name: ClassVar[PolicyName] = PolicyName.vis_no_occl
    occlusion: ClassVar[visibility.Mode] = visibility.Mode.no_occlusion

    def utilities(self, views: Views, belief: Belief, index: jax.Array, intrinsics: Intrinsics,
                  config: NBVConfig) -> jax.Array:
        total = jnp.sum(_visible(belief, views, index, intrinsics, config, self.occlusion), axis=1)
        return safe_div(total, jnp.max(total))


@dataclasses.dataclass(frozen=True)
class VisOccl(VisNoOccl):
    """The paper's VisOccl: visibility through the z-buffer, no history."""

    name: ClassVar[PolicyName] = PolicyName.vis_occl
    occlusion: ClassVar[visibility.Mode] = visibility.Mode.paper


@dataclasses.dataclass(frozen=True)
class VisOcclHist(_ScoresCandidates):
    """The paper's VisOcclHist: visibility through the z-buffer times the history weight (Eq. 6-8)."""

    name: ClassVar[PolicyName] = PolicyName.vis_occl_hist

    def utilities(self, views: Views, belief: Belief, index: jax.Array, intrinsics: Intrinsics,
                  config: NBVConfig) -> jax.Array:
        total = jnp.sum(_visible(belief, views, index, intrinsics, config, visibility.Mode.paper), axis=1)
        return _with_history(total, views, index, config)


@dataclasses.dataclass(frozen=True)
class VisOcclHistUnc(_ScoresCandidates):
    """Beyond the paper: VisOcclHist with each segment's visibility weighted by how unsure the system still
    is of it (``Belief.uncertainty``, measured by ``uncertainty``: see there), so views go to the objects
    not yet recognised."""

    name: ClassVar[PolicyName] = PolicyName.vis_occl_hist_unc
    uncertainty: Uncertainty = Uncertainty.rho_margin  # what the episode's belief measures for it

    def __post_init__(self) -> None:
        check_bounds(self, "nbv.vis_occl_hist_unc.")

    def utilities(self, views: Views, belief: Belief, index: jax.Array, intrinsics: Intrinsics,
                  config: NBVConfig) -> jax.Array:
        if belief.uncertainty is None:
            raise ValueError("nbv: vis_occl_hist_unc needs Belief.uncertainty [N] (nbv.uncertainty)")
        seen = _visible(belief, views, index, intrinsics, config, visibility.Mode.paper)
        return _with_history(jnp.sum(seen * belief.uncertainty[None, :], axis=1), views, index, config)


@dataclasses.dataclass(frozen=True)
class InfoGain(_ScoresCandidates):
    """Beyond the paper: volumetric information gain on the TSDF (``information.gain``: unobserved voxels
    the view's rays reach before an observed surface), normalised over the candidates, times the history
    weight (Eq. 6)."""

    name: ClassVar[PolicyName] = PolicyName.info_gain
    gain: information.GainConfig = dataclasses.field(default_factory=information.GainConfig)

    def utilities(self, views: Views, belief: Belief, index: jax.Array, intrinsics: Intrinsics,
                  config: NBVConfig) -> jax.Array:
        if belief.volume is None:
            raise ValueError("nbv: info_gain needs Belief.volume (the fused TSDF)")
        g = information.gain(belief.volume, views.T_wc[index], intrinsics, self.gain)
        return _with_history(g, views, index, config)


@dataclasses.dataclass(frozen=True)
class Continuous:
    """Beyond the paper: gradient ascent of the soft utility (``visibility.soft_counts`` times the history
    weight, normalised by the best soft candidate) over the camera's place on the view sphere (azimuth,
    elevation; it looks at the sphere's centre), from the ``starts`` best discrete candidates; the best
    iterate is kept (so it never ends below its start), then snapped to the nearest viewpoint
    (``continuous_view`` gives the unsnapped pose: ``episode.off_grid`` goes there, for views rendered on
    demand)."""

    name: ClassVar[PolicyName] = PolicyName.continuous
    steps: int = bounded(20, ge=1)
    step_size: float = bounded(0.05, gt=0.0)  # rad per normalised gradient step
    starts: int = bounded(3, ge=1)  # the best discrete candidates the ascents start from

    def __post_init__(self) -> None:
        check_bounds(self, "nbv.continuous.")

    def choose(self, views: Views, belief: Belief, key: jax.Array, intrinsics: Intrinsics,
               config: NBVConfig) -> jax.Array:
        T, _, _ = continuous_view(self, views, belief, intrinsics, config)
        d = jnp.linalg.norm(views.T_wc[:, :3, 3] - T[:3, 3], axis=-1).at[views.current].set(jnp.inf)
        return jnp.argmin(d).astype(jnp.int32)


@dataclasses.dataclass(frozen=True)
class Learned(_ScoresCandidates):
    """Beyond the paper: a network's score of each candidate from the state the hand-made policies read
    (``planning.learned``: features, ``ViewScorer``), the best within the radius taken (Eq. 8). Its weights
    are traced (``Belief.weights``, loaded by the episode's set-up from ``weights``: a shipped name or a
    ``.msgpack`` written by ``jaxcls train-policy``); nothing here is trained."""

    name: ClassVar[PolicyName] = PolicyName.learned
    weights: str = ""  # a shipped name (``learned.SHIPPED_WEIGHTS``) or a path; "" = none given

    def choose(self, views: Views, belief: Belief, key: jax.Array, intrinsics: Intrinsics,
               config: NBVConfig) -> jax.Array:
        """The best-scored unvisited candidate within the radius (a visited one only where none is left): the
        choices the oracle ranks (``protocol.oracle_rollouts``), so a network imitating it never revisits."""
        index, ok = candidates(views, config)
        return _argmax_candidate(self.utilities(views, belief, index, intrinsics, config), index,
                                 unvisited_first(views, index, ok))

    def utilities(self, views: Views, belief: Belief, index: jax.Array, intrinsics: Intrinsics,
                  config: NBVConfig) -> jax.Array:
        from jaxcls.planning import learned  # (it imports this module)

        if belief.weights is None:
            raise ValueError("nbv: the learned policy needs its weights in Belief.weights (the episode's set-up "
                             "loads nbv.learned.weights)")
        ok = candidates(views, config)[1]
        return learned.scores(belief.weights, views, belief, index, ok, intrinsics, config)


Policy = Random | VisNoOccl | VisOccl | VisOcclHist | VisOcclHistUnc | InfoGain | Continuous | Learned
POLICIES: dict[PolicyName, type[Policy]] = {p.name: p for p in (Random, VisNoOccl, VisOccl, VisOcclHist, VisOcclHistUnc,
                                                                InfoGain, Continuous, Learned)}
WEIGHTED: frozenset[PolicyName] = frozenset({PolicyName.learned})  # policies that read ``Belief.weights``


def policy(name: PolicyName | str) -> Policy:
    """The policy registered as ``name`` (``POLICIES``) with its default parameters (``NBVConfig.policy``
    gives it with a config's)."""
    if name not in POLICIES:
        raise ValueError(f"nbv: unknown policy {name!r}; choose one of {[str(p) for p in PolicyName]}")
    return POLICIES[PolicyName(name)]()


@dataclasses.dataclass(frozen=True)
class NBVConfig:
    """The ``nbv:`` block: candidate set, history weight, visibility, and the parameters of the policies
    that have any (``policy`` puts them together with the episode's choice)::

        nbv:
          radius: 0.5
          continuous: {steps: 20, step_size: 0.05, starts: 3}
          info_gain: {gain: {...}}
          vis_occl_hist_unc: {uncertainty: rho_margin}
          learned: {weights: runs/policy/policy.msgpack}
    """

    radius: float = bounded(0.5, gt=0.0)  # m: candidates lie within this of the current view (the paper's r)
    max_candidates: int = bounded(32, ge=1)  # the nearest ones, a static shape
    history: History = History.min  # Eq. 6 over the visited views (``History``)
    visibility: visibility.VisibilityConfig = dataclasses.field(default_factory=visibility.VisibilityConfig)
    vis_occl_hist_unc: VisOcclHistUnc = dataclasses.field(default_factory=VisOcclHistUnc)
    info_gain: InfoGain = dataclasses.field(default_factory=InfoGain)
    continuous: Continuous = dataclasses.field(default_factory=Continuous)
    learned: Learned = dataclasses.field(default_factory=Learned)

    def __post_init__(self) -> None:
        check_bounds(self, "nbv.")

    def policy(self, name: PolicyName | str) -> Policy:
        """The policy ``name`` with this block's parameters for it (the paper's policies have none)."""
        configured = {p.name: p for p in (self.vis_occl_hist_unc, self.info_gain, self.continuous, self.learned)}
        return configured.get(PolicyName(name)) or policy(name)


class Views(struct.PyTreeNode):
    """The viewpoints of an episode and where the camera has been.

    T_wc: [V, 4, 4] camera-to-world poses of the viewpoints; visited: [V] bool; current: [] i32.
    """

    T_wc: jax.Array
    visited: jax.Array
    current: jax.Array

    @classmethod
    def start(cls, T_wc: jax.Array, current: int | jax.Array) -> Views:
        T_wc = jnp.asarray(T_wc, jnp.float32)
        current = jnp.asarray(current, jnp.int32)
        return cls(T_wc=T_wc, visited=jnp.zeros(T_wc.shape[0], bool).at[current].set(True), current=current)

    def move(self, index: jax.Array) -> Views:
        return self.replace(visited=self.visited.at[index].set(True), current=jnp.asarray(index, jnp.int32))


class Belief(struct.PyTreeNode):
    """What the planner knows of the scene: each segment's aligned model cuboid and how sure it is.

    corners: [N, 8, 3] model frame (m); poses: [N, 4, 4] model-to-world (refinement's Eq. 4); live: [N] bool;
    uncertainty: [N] in [0, 1] (``uncertainty``; only ``vis_occl_hist_unc`` reads it); volume: the fused
    TSDF (only ``info_gain`` reads it); weights: the learned policy's network (only ``learned`` reads them); rho:
    [N, k] refinement's rho of each candidate class (Eq. 2; only the learned policy's layout 3 reads it).
    """

    corners: jax.Array
    poses: jax.Array
    live: jax.Array
    uncertainty: jax.Array | None = None
    volume: TSDFVolume | None = None
    weights: Any = None
    rho: jax.Array | None = None


def uncertainty(rho: jax.Array, probs: jax.Array, kind: Uncertainty = Uncertainty.rho_margin) -> jax.Array:
    """[N] in [0, 1]: how unsure the system is of each segment's refined class.

    rho: [N, k] refinement's rho per candidate (``Refinement.rho``); probs: [N, M] calibrated class scores.
    ``rho_margin`` (the default): 1 - (best rho - second best), ``entropy``: the scores' entropy over
    log M, ``one_minus_rho``: 1 - best rho. On segments of cluttered scenes the rho margin predicts a wrong
    refined class best (AUROC 0.92-0.93 against 0.79-0.82 for the entropy and 0.56-0.60 for 1 - rho;
    RESULTS.md, next-best-view)."""
    kind = Uncertainty(kind)
    if kind is Uncertainty.rho_margin:
        top = jax.lax.top_k(rho, min(2, rho.shape[1]))[0]
        margin = top[:, 0] - (top[:, 1] if top.shape[1] > 1 else 0.0)
        return jnp.clip(1.0 - margin, 0.0, 1.0)
    if kind is Uncertainty.entropy:
        p = jnp.clip(probs, 1e-12, 1.0)
        return jnp.clip(-jnp.sum(p * jnp.log(p), axis=1) / jnp.log(probs.shape[1]), 0.0, 1.0)
    return jnp.clip(1.0 - jnp.max(rho, axis=1), 0.0, 1.0)


def candidates(views: Views, config: NBVConfig) -> tuple[jax.Array, jax.Array]:
    """The move's candidates: (index [K] i32 of the ``max_candidates`` viewpoints nearest the current one,
    the current one excluded; ok [K] bool those within ``radius``)."""
    position = views.T_wc[:, :3, 3]
    distance = jnp.linalg.norm(position - position[views.current], axis=-1)
    distance = distance.at[views.current].set(jnp.inf)
    K = min(config.max_candidates, position.shape[0])
    order = jnp.argsort(distance)[:K]
    return order, distance[order] <= config.radius


def random_walk(rng: np.random.Generator, T_wc: np.ndarray, length: int, config: NBVConfig = NBVConfig()
                ) -> list[int]:
    """``length`` viewpoint indices (at most V) of a host-side random walk over ``T_wc: [V, 4, 4]``: a random
    start, then each time a random unvisited candidate (``candidates``, within ``config.radius``), or the
    nearest unvisited viewpoint when none is left: the Random policy's rule, drawn from a NumPy ``rng``
    (training clouds and experiments walk so)."""
    T_wc = np.asarray(T_wc, np.float32)
    V = len(T_wc)
    every = dataclasses.replace(config, max_candidates=V)
    views = Views.start(T_wc, int(rng.integers(V)))
    path = [int(views.current)]
    while len(path) < min(length, V):
        index, ok = (np.asarray(a) for a in candidates(views, every))
        fresh = sorted(int(v) for v in index[ok] if v not in path)
        if not fresh:
            fresh = [next(int(v) for v in index if v not in path)]  # index is sorted nearest first
        path.append(int(rng.choice(fresh)))
        views = views.move(path[-1])
    return path


def unvisited_first(views: Views, index: jax.Array, ok: jax.Array) -> jax.Array:
    """[K] bool the candidates ``index`` [K] a move may take: those within the radius (``ok``) not yet visited,
    or, where every one is visited, those within the radius."""
    fresh = ok & ~views.visited[index]
    return jnp.where(jnp.any(fresh), fresh, ok)


def history_weight(views: Views, index: jax.Array, config: NBVConfig) -> jax.Array:
    """[K] Eq. 6 for the viewpoints ``index`` [K]: 1 - G(D) with G(0) = 1, sigma = radius / 2, over the
    visited views by ``config.history`` ("min": the nearest visited view decides)."""
    position = views.T_wc[:, :3, 3]
    d = jnp.linalg.norm(position[index][:, None, :] - position[None, :, :], axis=-1)  # [K, V]
    sigma = config.radius / 2
    one_minus_g = 1.0 - jnp.exp(-(d**2) / (2 * sigma**2))
    if config.history is History.min:
        return jnp.min(jnp.where(views.visited[None], one_minus_g, 1.0), axis=1)
    return jnp.max(jnp.where(views.visited[None], one_minus_g, 0.0), axis=1)


def _sphere(views: Views) -> tuple[jax.Array, jax.Array]:
    """(centre [3], radius []) of the view sphere: the point nearest every viewpoint's optical axis."""
    o, d = views.T_wc[:, :3, 3], views.T_wc[:, :3, 2]
    P = jnp.eye(3)[None] - d[:, :, None] * d[:, None, :]  # projectors orthogonal to each axis
    centre = jnp.linalg.solve(jnp.sum(P, axis=0) + 1e-9 * jnp.eye(3), jnp.einsum("vij,vj->i", P, o))
    return centre, jnp.mean(jnp.linalg.norm(o - centre, axis=-1))


def _camera(angles: jax.Array, centre: jax.Array, radius: jax.Array) -> jax.Array:
    """[4, 4] T_wc of a camera at (azimuth, elevation) on the view sphere, looking at its centre (OpenCV
    axes, image down along -z as ``geometry.look_at``)."""
    a, e = angles[0], angles[1]
    eye = centre + radius * jnp.stack([jnp.cos(e) * jnp.cos(a), jnp.cos(e) * jnp.sin(a), jnp.sin(e)])
    return geometry.look_at(eye, centre, xp=jnp)


class _Ascent(NamedTuple):
    """The continuous policy's gradient ascent: x [2] (azimuth, elevation) rad now, best_x [2] the best
    iterate so far, best_u [] its soft utility."""

    x: jax.Array
    best_x: jax.Array
    best_u: jax.Array


def continuous_view(policy_config: Continuous, views: Views, belief: Belief, intrinsics: Intrinsics,
                    config: NBVConfig = NBVConfig()) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The continuous policy's view before snapping: (T_wc [4, 4], its soft utility [], the best discrete
    candidate's soft utility []), utilities normalised by the best candidate's soft count."""
    index, ok = candidates(views, config)
    centre, radius = _sphere(views)
    soft = dataclasses.replace(config.visibility, mode="paper")
    seen = jnp.sum(visibility.soft_counts(belief.corners, belief.poses, belief.live, views.T_wc[index], intrinsics,
                                          soft), axis=1)
    scale = jnp.maximum(jnp.max(jnp.where(ok, seen, 0.0)), 1e-6)
    position = views.T_wc[:, :3, 3]
    sigma = config.radius / 2

    def utility(angles):
        T = _camera(angles, centre, radius)
        count = jnp.sum(visibility.soft_counts(belief.corners, belief.poses, belief.live, T[None], intrinsics, soft))
        d2 = jnp.sum((position - T[:3, 3]) ** 2, axis=-1)
        weight = 1.0 - jnp.max(jnp.where(views.visited, jnp.exp(-d2 / (2 * sigma**2)), 0.0))
        return weight * count / scale

    discrete = history_weight(views, index, config) * seen / scale
    discrete = jnp.where(ok, discrete, -jnp.inf)
    S = min(policy_config.starts, index.shape[0])
    best_start = index[jax.lax.top_k(discrete, S)[1]]
    rel = position[best_start] - centre
    starts = jnp.stack([jnp.arctan2(rel[:, 1], rel[:, 0]),
                        jnp.arcsin(jnp.clip(rel[:, 2] / radius, -1.0, 1.0))], axis=-1)
    value_and_grad = jax.value_and_grad(utility)

    def ascend(angles):
        def step(carry: _Ascent, _) -> tuple[_Ascent, None]:
            x, best_x, best_u = carry
            u, g = value_and_grad(x)
            better = u > best_u
            best_x, best_u = jnp.where(better, x, best_x), jnp.where(better, u, best_u)
            g = jnp.nan_to_num(g)
            x = x + policy_config.step_size * g / jnp.maximum(jnp.linalg.norm(g), 1e-12)
            x = x.at[1].set(jnp.clip(x[1], 0.02, jnp.pi / 2 - 0.02))
            return _Ascent(x, best_x, best_u), None

        start = _Ascent(angles, angles, jnp.asarray(-jnp.inf, jnp.float32))
        (x, best_x, best_u), _ = jax.lax.scan(step, start, None, length=policy_config.steps)
        u = utility(x)
        return jnp.where(u > best_u, x, best_x), jnp.maximum(u, best_u)

    ends, values = jax.vmap(ascend)(starts)
    k = jnp.argmax(values)
    return _camera(ends[k], centre, radius), values[k], jnp.max(discrete)


def choose(policy_config: Policy, views: Views, belief: Belief, key: jax.Array, intrinsics: Intrinsics,
           config: NBVConfig = NBVConfig()) -> jax.Array:
    """[] i32: the next viewpoint by ``policy_config``'s own kernel (Eq. 8, or the policy's own rule); see
    the module docstring for the choices made on degenerate inputs. Pure and jit-able (``choose_jit``)."""
    return policy_config.choose(views, belief, key, intrinsics, config)


choose_jit = jax.jit(choose, static_argnames=("policy_config", "intrinsics", "config"))
