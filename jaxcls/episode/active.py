"""The active episode (paper Sec. 3, Fig. 2) as a functional environment: ``reset`` and ``step`` over an
``EpisodeState`` pytree, in the manner of Brax.

A move: the frame of the view the camera stands at is fused, the surface segmented and classified
(``perception.observation``'s stages), every segment's candidates refined by registration (GR, Eq. 2-4;
``perception.refine``), and the next view chosen by a policy (Eq. 5-8; ``planning.nbv``)::

    episode = Episode.create(spec, library, EpisodeConfig(policy="vis_occl_hist"))
    state = reset(episode, viewpoints, start=0, key=jax.random.PRNGKey(0))
    while not state.done:
        depth, T_wc = source.frame(int(state.next_view))      # a ViewSource (episode.sources)
        state = step_jit(episode, state, depth, T_wc)

``step`` is pure JAX with the JAX segmentation (the default): one jitted function with no host round trip,
``vmap``-able over episodes (``in_axes=(None, 0, 0, 0)``). ``rollout`` runs a whole episode on frames
already in memory (a dataset scene: the loop only indexes them) as one ``lax.scan`` under one jit, the
PureJaxRL shape. ``run`` (``episode.runner``) is the host driver that times each stage and records each move.

Static settings (``EpisodeConfig``, ``RefineConfig``, ``NBVConfig``, the perception ``Spec``'s config) are
hashed fields of ``Episode``: a change recompiles; the classifier's weights and the model library are
traced leaves.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxcls.config import bounded, check_bounds
from jaxcls.perception import observation, pose
from jaxcls.perception.observation import Observation
from jaxcls.perception.refine import ModelLibrary, RefineConfig, Refinement, YawSource, explained, refine
from jaxcls.perception.settings import ObjectCount, Spec
from jaxcls.planning import learned, nbv

STABLE_DISTANCE = 0.05  # m: a segment is the same object as last move's nearest segment within this


class Decision(enum.StrEnum):
    """How a segment's refined class is decided (GR on): ``last``, from this move alone (Eq. 3); from the
    class evidence its object has gathered over the moves (``gather_evidence``): ``evidence``, each class's
    summed scores; ``best``, each class's best score of any move. GR off: the prior, whatever this says."""

    last = "last"
    evidence = "evidence"
    best = "best"


@dataclasses.dataclass(frozen=True)
class StopConfig:
    """The adaptive stop (off by default): stop once every live segment's refined class has held for
    ``stable_moves`` moves with its rho at least ``min_rho``."""

    stable_moves: int = bounded(0, ge=0)  # 0 = off: always ``moves`` moves
    min_rho: float = bounded(0.3, ge=0.0, le=1.0)

    def __post_init__(self) -> None:
        check_bounds(self, "episode.stop.")


@dataclasses.dataclass(frozen=True)
class EpisodeConfig:
    """The ``episode:`` block: how many moves, which policy, GR on or off, when to stop early."""

    moves: int = bounded(10, ge=1)  # T: frames fused (the paper's 10)
    policy: nbv.PolicyName = nbv.PolicyName.vis_occl_hist  # its parameters: the ``nbv:`` block
    refinement: bool = True  # GR (Eq. 2-4); off: the prior class, the model upright under the centroid
    # With the continuous policy: go to the view it found, off the fixed viewpoints (a source that renders
    # any pose, ``sources.Rendered``); the nearest viewpoint stands for it in the candidates and the history.
    off_grid: bool = False
    decision: Decision = Decision.evidence  # how a segment's refined class is decided (``Decision``)
    evidence_decay: float = bounded(1.0, ge=0.0, le=1.0)  # last move's evidence counts this much this move
    stop: StopConfig = dataclasses.field(default_factory=StopConfig)

    def __post_init__(self) -> None:
        check_bounds(self, "episode.")
        if self.off_grid and self.policy is not nbv.PolicyName.continuous:
            raise ValueError(f"episode.off_grid needs episode.policy=continuous, got {self.policy}")


@struct.dataclass
class Episode:
    """Everything a move reads that is not the episode's state. Build it with ``Episode.create``.

    spec: perception's settings and the classifier (traced weights); library: the models GR registers
    onto; corners: [L, 8, 3] f32 each model's bounding-box corners in its frame (the planner's cuboids,
    Eq. 5); yaw_orders: [M] i32 the classifier's yaw-symmetry orders; config, refine_config, nbv_config: static
    settings.
    """

    spec: Spec
    library: ModelLibrary
    corners: jax.Array
    yaw_orders: jax.Array
    config: EpisodeConfig = struct.field(pytree_node=False, default=EpisodeConfig())
    refine_config: RefineConfig = struct.field(pytree_node=False, default=RefineConfig())
    nbv_config: nbv.NBVConfig = struct.field(pytree_node=False, default=nbv.NBVConfig())
    # A switched episode (``switched``): the policy and GR are traced values, one program for every row.
    choice: Choice | None = None
    policies: tuple[nbv.PolicyName, ...] = struct.field(pytree_node=False, default=())
    # The learned policy's network (traced; ``planning.learned``), None where no policy reads it.
    policy_weights: Any = None

    @classmethod
    def create(cls, spec: Spec, library: ModelLibrary, config: EpisodeConfig | None = None,
               refine_config: RefineConfig | None = None, nbv_config: nbv.NBVConfig | None = None,
               policy_weights: Any = None) -> Episode:
        """Check that the pieces fit (a classifier, of the library's classes; a yaw head if GR's yaws are
        learned; weights for a learned policy), resolve GR's yaw source for these weights
        (``RefineConfig.resolve``: the episode keeps what runs) and stack the model cuboids."""
        config, refine_config = config or EpisodeConfig(), refine_config or RefineConfig()
        if spec.classifier is None:
            raise ValueError("episode: the perception spec has no classifier (Spec.create(..., classifier=...))")
        if config.policy in nbv.WEIGHTED and policy_weights is None:
            raise ValueError(f"episode: policy {config.policy} needs its weights (nbv.learned.weights: a file "
                             f"written by jaxcls train-policy, or a shipped name: {', '.join(learned.SHIPPED_WEIGHTS)};"
                             " RESULTS.md, \"The learned view policy\", says which classifier each was trained for)")
        spec.classifier.check_classes(library.classes, "model library")
        refine_config = refine_config.resolve(spec.classifier.config.yaw_head, "the classifier's weights")
        points = np.asarray(library.targets.points, np.float32)  # [L, S, 3]
        lo, hi = points.min(axis=1), points.max(axis=1)
        pick = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], bool)  # [8, 3]
        corners = np.where(pick[None], hi[:, None, :], lo[:, None, :])
        orders = spec.classifier.yaw_orders or (1,) * len(spec.classifier.classes)
        # (NumPy put on the device: no conversion program to compile or load)
        return cls(spec=spec, library=library, corners=jax.device_put(corners),
                   yaw_orders=jax.device_put(np.asarray(orders, np.int32)),
                   config=config, refine_config=refine_config, nbv_config=nbv_config or nbv.NBVConfig(),
                   policy_weights=policy_weights)

    @property
    def policy(self) -> nbv.Policy:
        """The episode's policy with its parameters (``episode.policy``, the ``nbv:`` block)."""
        return self.nbv_config.policy(self.config.policy)

    def switched(self, policies: tuple[nbv.PolicyName | str, ...] | None = None) -> Episode:
        """This episode with its policy and GR as traced values (``Choice``): one compiled program runs any
        of ``policies`` with GR on or off, picked by ``choose`` without compiling again (Table 1's rows). The
        static ``config`` keeps every other setting; its policy and GR are set by ``choose``. Not with
        ``off_grid``. Under ``vmap`` over episodes of one choice (the episode unbatched) only the chosen
        policy's kernel and GR or its absence run (``lax.switch``, ``lax.cond``). Default: every policy, the
        learned one where the episode has its weights."""
        if policies is None:
            policies = tuple(p for p in nbv.PolicyName if p not in nbv.WEIGHTED or self.policy_weights is not None)
        policies = tuple(nbv.PolicyName(p) for p in policies)
        if self.config.off_grid:
            raise ValueError("episode: off_grid views are rendered on demand; a switched episode indexes frames")
        if not policies or len(set(policies)) != len(policies):
            raise ValueError(f"episode: switched needs distinct policies, got {policies}")
        if self.policy_weights is None and nbv.WEIGHTED & set(policies):
            raise ValueError(f"episode: policies {sorted(nbv.WEIGHTED & set(policies))} need their weights "
                             "(nbv.learned.weights), and this episode has none")
        config = dataclasses.replace(self.config, policy=policies[0], refinement=True)
        chosen = self.config.policy if self.config.policy in policies else policies[0]
        return self.replace(config=config, policies=policies,
                            choice=Choice.create(policies.index(chosen), self.config.refinement))

    def choose(self, policy: nbv.PolicyName | str, refinement: bool) -> Episode:
        """A switched episode (``switched``) set to ``policy`` with GR on or off: same program, other row."""
        if self.choice is None:
            raise ValueError("episode: choose needs a switched episode (Episode.switched)")
        policy = nbv.PolicyName(policy)
        if policy not in self.policies:
            raise ValueError(f"episode: policy {policy} is not among this program's {[str(p) for p in self.policies]}")
        return self.replace(choice=Choice.create(self.policies.index(policy), refinement))

    def refinement_on(self) -> bool | jax.Array:
        """GR on: the static setting, or the traced choice of a switched episode ([] bool)."""
        return self.config.refinement if self.choice is None else self.choice.refinement


@struct.dataclass
class Choice:
    """A switched episode's row as traced values: policy [] i32 (index into ``Episode.policies``), refinement
    [] bool (GR on)."""

    policy: jax.Array
    refinement: jax.Array

    @classmethod
    def create(cls, policy: int, refinement: bool) -> Choice:
        return cls(policy=jax.device_put(np.int32(policy)), refinement=jax.device_put(np.bool_(refinement)))


@struct.dataclass
class EpisodeState:
    """The episode so far (N segments, k candidates, V viewpoints, T moves).

    observation: perception's state (TSDF, surface, segments, probs, yaw); refinement: each segment's
    prior class, candidates, rho, refined class and pose (``Refinement``); views: the viewpoints, those
    fused (``visited``) and the last one (``current``); path: [T] i32 the views fused, in order (-1 =
    not yet); cameras: [T, 3] m where the frames were taken (NaN = not yet); next_view: [] i32 where the
    policy sends the camera (the next frame's view; with ``off_grid``, the viewpoint nearest it); next_pose:
    [4, 4] T_wc the next frame is taken from (the viewpoint's, or the continuous policy's own, as the robot is
    told it); stable: [N] i32 moves each segment's refined class has held; evidence: [N, M] f32 the class
    evidence each segment's object has gathered (``refinement``); done: [] bool no further move (T reached or
    the adaptive stop); key: the episode's PRNG key (split by each view choice).
    """

    observation: Observation
    refinement: Refinement
    views: nbv.Views
    path: jax.Array
    cameras: jax.Array
    next_view: jax.Array
    next_pose: jax.Array
    stable: jax.Array
    evidence: jax.Array
    done: jax.Array
    key: jax.Array

    @property
    def moves(self) -> jax.Array:
        """[] i32 frames fused so far."""
        return self.observation.frames


def empty_refinement(num_segments: int, k: int) -> Refinement:
    """The refinement before any segment exists: nothing valid, identity poses."""
    zeros = jnp.zeros(num_segments, jnp.int32)
    return Refinement(prior=zeros, candidates=jnp.zeros((num_segments, k), jnp.int32),
                      rho=jnp.zeros((num_segments, k), jnp.float32), refined=zeros,
                      pose=jnp.tile(jnp.eye(4, dtype=jnp.float32), (num_segments, 1, 1)),
                      model=jnp.full(num_segments, -1, jnp.int32), valid=jnp.zeros(num_segments, bool))


def reset(episode: Episode, viewpoints: jax.Array, start: int | jax.Array, key: jax.Array) -> EpisodeState:
    """The state before the first frame: the camera at viewpoint ``start`` of ``viewpoints: [V, 4, 4]``
    (T_wc), nothing fused. A concrete ``start`` outside 0..V-1 is a ValueError."""
    viewpoints = jnp.asarray(viewpoints, jnp.float32)
    if viewpoints.ndim != 3 or viewpoints.shape[1:] != (4, 4):
        raise ValueError(f"episode: viewpoints must be [V, 4, 4] camera-to-world poses, got {viewpoints.shape}")
    if isinstance(start, int | np.integer) and not 0 <= start < viewpoints.shape[0]:
        raise ValueError(f"episode: start view {int(start)} is outside 0..{viewpoints.shape[0] - 1} "
                         f"({viewpoints.shape[0]} viewpoints)")
    N = episode.spec.num_segments
    k = min(episode.refine_config.top_k, len(episode.library.classes))
    start = jnp.asarray(start, jnp.int32)
    views = nbv.Views(T_wc=viewpoints, visited=jnp.zeros(viewpoints.shape[0], bool), current=start)
    return EpisodeState(observation=observation.init_state(episode.spec), refinement=empty_refinement(N, k),
                        views=views, path=jnp.full(episode.config.moves, -1, jnp.int32),
                        cameras=jnp.full((episode.config.moves, 3), jnp.nan, jnp.float32), next_view=start,
                        next_pose=viewpoints[start], stable=jnp.zeros(N, jnp.int32),
                        evidence=jnp.zeros(state_classes(episode), jnp.float32), done=jnp.zeros((), bool), key=key)


def state_classes(episode: Episode) -> tuple[int, int]:
    """(N, M): segments and classes, the shape of ``EpisodeState.evidence``."""
    return episode.spec.num_segments, len(episode.spec.classifier.classes)


# --- the stages of a move, each (episode, state, depth, T_wc) -> state ------------------------------------

def _perception_stage(stage):
    def run(episode: Episode, state: EpisodeState, depth: jax.Array, T_wc: jax.Array) -> EpisodeState:
        return state.replace(observation=stage(episode.spec, state.observation, depth, T_wc))

    run.__doc__ = stage.__doc__
    return run


def reconstruction(episode: Episode, state: EpisodeState, depth: jax.Array, T_wc: jax.Array) -> EpisodeState:
    """Stage 1, reconstruction (``observation.reconstruct``: the camera tracked, the frame fused); the
    camera's position in ``cameras`` becomes the tracked one."""
    obs = observation.reconstruct(episode.spec, state.observation, depth, T_wc)
    t = obs.frames - 1
    return state.replace(observation=obs, cameras=state.cameras.at[t].set(obs.tracking.pose[:3, 3], mode="drop"))


def arrive(episode: Episode, state: EpisodeState, depth: jax.Array | None = None,
           T_wc: jax.Array | None = None) -> EpisodeState:
    """The camera is at ``next_view`` (the frame's ``T_wc``): it joins the visited views, the path and the
    cameras (before its frame is fused)."""
    views = state.views.move(state.next_view)
    t = state.observation.frames
    position = jnp.asarray(T_wc, jnp.float32)[:3, 3] if T_wc is not None else views.T_wc[state.next_view, :3, 3]
    return state.replace(views=views, path=state.path.at[t].set(state.next_view, mode="drop"),
                         cameras=state.cameras.at[t].set(position, mode="drop"))


def seen_from(state: EpisodeState) -> jax.Array:
    """[T, 3] world positions of the cameras fused so far (NaN rows: moves not made), for the
    visibility-aware rho (``icp.registration_ratio``)."""
    return state.cameras


def prior_only(episode: Episode, obs: Observation) -> Refinement:
    """GR off: the prior class (Eq. 1) and, for the planner, its first model upright under the segment's
    centroid, turned by the yaw head's estimate (0 without a head)."""
    seg = obs.segments
    k = min(episode.refine_config.top_k, obs.probs.shape[1])
    _, candidates = jax.lax.top_k(obs.probs, k)
    prior = candidates[:, 0]
    model = episode.library.class_models[prior, 0]
    yaw = jnp.take_along_axis(obs.yaw, prior[:, None], axis=1)
    poses = jax.vmap(lambda p, m, c, y: pose.initial_poses(p, m, c, episode.spec.table_height, y)[0])(
        seg.points, seg.mask, episode.library.centroid[model], yaw)
    valid = jnp.any(seg.mask, axis=1)
    return Refinement(prior=prior, candidates=candidates, rho=jnp.zeros(candidates.shape, jnp.float32),
                      refined=prior, pose=jnp.where(valid[:, None, None], poses, jnp.eye(4, dtype=poses.dtype)),
                      model=jnp.where(valid, model, -1), valid=valid)


def centroids(obs: Observation) -> jax.Array:
    """[N, 3] m the segments' centroids (0 for an empty segment)."""
    seg = obs.segments
    w = seg.mask.astype(jnp.float32)
    return jnp.sum(w[..., None] * seg.points, axis=1) / jnp.maximum(jnp.sum(w, axis=1), 1.0)[:, None]


def gather_evidence(config: EpisodeConfig, carried: jax.Array, move: jax.Array) -> jax.Array:
    """[N, M] each segment's class evidence after this move: ``carried`` [N, M], its object's evidence after
    the last move (0 for a new object), and ``move`` [N, M], this move's class scores. ``decision = "best"``:
    each class's best score of any move, max(decay x carried, move): a class PointNet ranked among the top-k
    only late, once the object was seen well, wins as soon as its score beats every earlier one; otherwise
    (``"evidence"``, and ``"last"``, which keeps it for the record) the decayed sum decay x carried + move:
    consistent moves add up. Under either a move that fits every class badly cannot overturn the earlier ones."""
    decayed = config.evidence_decay * carried
    if config.decision is Decision.best:
        return jnp.maximum(decayed, move)
    return decayed + move


def refinement(episode: Episode, state: EpisodeState, depth: jax.Array | None = None,
               T_wc: jax.Array | None = None) -> EpisodeState:
    """Stage 4, geometric refinement (Eq. 2-4) of every segment, or the prior alone with GR off; the class
    evidence of each segment's object; then how many moves each segment's refined class has held.

    A segment is the same object as last move's whose aligned model stands nearest in xy, within
    ``STABLE_DISTANCE``. Its evidence gathers that object's (``gather_evidence``) and this move's scores: rho
    of each candidate class (Eq. 2; x PointNet's probability under ``refine.decision = product``; 0 for the
    other classes), or PointNet's probabilities with GR off. With ``decision`` "evidence" or "best" and GR
    on, its class is the evidence's argmax: a move whose segment fits every model badly (a merge, a sliver)
    cannot overturn what earlier moves saw; with ``"last"``, this move's class (Eq. 3). With GR off the class
    stays PointNet's (the prior, as the paper's rows without GR). The pose and model stay this move's best
    registration. With the count estimated (``shapes.num_objects``) and GR on, a segment whose points lie on a
    larger segment's aligned model (``segmentation.explained_share``, ``refine.explained``) is no object: not
    live, no model, rho 0."""
    obs = state.observation
    gr = episode.refinement_on()

    def registered() -> Refinement:
        learned = episode.refine_config.yaw_source is YawSource.learned
        fitted = refine(obs.segments.points, obs.segments.mask, obs.probs, episode.library, episode.refine_config,
                        episode.spec.table_height, seen_from(state), yaw=obs.yaw if learned else None,
                        yaw_orders=episode.yaw_orders if learned else None)
        rule = episode.spec.config.segmentation
        if episode.spec.config.shapes.num_objects is not ObjectCount.estimated or not rule.explained_share:
            return fitted
        gone = explained(obs.segments.points, obs.segments.mask, fitted, episode.library, rule.explained_distance,
                         rule.explained_share, episode.refine_config.icp.points)
        # An explained part is no object: not live, no model, rho 0, identity pose (its classes as GR found them).
        return fitted.replace(valid=fitted.valid & ~gone, model=jnp.where(gone, -1, fitted.model),
                              rho=jnp.where(gone[:, None], 0.0, fitted.rho),
                              pose=jnp.where(gone[:, None, None], jnp.eye(4, dtype=fitted.pose.dtype), fitted.pose))

    if episode.choice is None:  # the static setting: one branch compiled
        new = registered() if gr else prior_only(episode, obs)
    else:  # a switched episode's traced choice: both compiled, the chosen one runs
        new = jax.lax.cond(gr, registered, lambda: prior_only(episode, obs))
    old = state.refinement
    # The same object as last move's segment whose aligned model stands nearest (xy of the base centres).
    d = jnp.linalg.norm(new.pose[:, None, :2, 3] - old.pose[None, :, :2, 3], axis=-1)
    d = jnp.where(old.valid[None, :], d, jnp.inf)
    match = jnp.argmin(d, axis=1)
    tracked = jnp.min(d, axis=1) <= STABLE_DISTANCE
    N, M = state.evidence.shape
    # The move's own class scores: with GR, refine.decision's (rho, or probability x rho); without, PointNet's.
    score = episode.refine_config.decision.scores(
        new.rho, jnp.take_along_axis(state.observation.probs, new.candidates, axis=1))
    registered_scores = jnp.zeros((N, M), jnp.float32).at[jnp.arange(N)[:, None], new.candidates].max(score)
    move = jnp.where(gr, registered_scores, state.observation.probs)
    carried = jnp.where(tracked[:, None], state.evidence[match], 0.0)
    evidence = jnp.where(new.valid[:, None], gather_evidence(episode.config, carried, move), 0.0)
    if episode.config.decision is not Decision.last:  # GR on: the evidence decides; off: PointNet's class
        decided = jnp.argmax(evidence, axis=1).astype(new.refined.dtype)
        by_evidence = gr & new.valid & (jnp.max(evidence, axis=1) > 0)
        new = new.replace(refined=jnp.where(by_evidence, decided, new.refined))
    same = tracked & (old.refined[match] == new.refined)
    stable = jnp.where(new.valid, jnp.where(same, state.stable[match] + 1, 1), 0)
    return state.replace(refinement=new, stable=stable, evidence=evidence)


def belief(episode: Episode, state: EpisodeState) -> nbv.Belief:
    """What the planner is told: each live segment's refined model cuboid and pose, its uncertainty and rho, the
    TSDF, the learned policy's weights."""
    r = state.refinement
    return nbv.Belief(corners=episode.corners[jnp.maximum(r.model, 0)], poses=r.pose, live=r.valid,
                      uncertainty=nbv.uncertainty(r.rho, state.observation.probs,
                                                  episode.nbv_config.vis_occl_hist_unc.uncertainty),
                      volume=state.observation.volume, weights=episode.policy_weights, rho=r.rho)


def planned_views(state: EpisodeState) -> nbv.Views:
    """The viewpoints as the planner scores them: the reported ones corrected by tracking's hand-eye estimate."""
    return state.views.replace(T_wc=state.observation.tracking.hand_eye.predict(state.views.T_wc))


def candidate_utilities(episode: Episode, state: EpisodeState) -> tuple[jax.Array, jax.Array, jax.Array]:
    """What the move's planning weighed (for viewers and reports; the step does not keep it): (index [K] i32 of
    the candidate viewpoints, ok [K] those within the radius, U [K] each one's utility by the episode's policy,
    Eq. 7 or the policy's own; NaN for a policy that scores no candidates, as Random)."""
    views = planned_views(state)
    index, ok = nbv.candidates(views, episode.nbv_config)
    policy = episode.policy
    if not hasattr(policy, "utilities"):
        return index, ok, jnp.full(index.shape, jnp.nan, jnp.float32)
    U = policy.utilities(views, belief(episode, state), index, episode.spec.intrinsics, episode.nbv_config)
    return index, ok, U


def planning(episode: Episode, state: EpisodeState, depth: jax.Array | None = None,
             T_wc: jax.Array | None = None) -> EpisodeState:
    """Stage 5, next-best-view: the policy's next view (Eq. 5-8), and whether the episode is done. The
    policy scores the viewpoints where the camera will be relative to the fused model: the reported
    viewpoints corrected by tracking's hand-eye estimate (``HandEye.predict``; unchanged with tracking off)."""
    key, sub = jax.random.split(state.key)
    hand_eye = state.observation.tracking.hand_eye
    views = planned_views(state)
    if episode.config.off_grid:  # the continuous policy's own view; its nearest viewpoint keeps the books
        model_pose, _, _ = nbv.continuous_view(episode.policy, views, belief(episode, state),
                                               episode.spec.intrinsics, episode.nbv_config)
        next_pose = hand_eye.unpredict(model_pose)
        position = state.views.T_wc[:, :3, 3]
        next_view = jnp.argmin(jnp.linalg.norm(position - next_pose[:3, 3], axis=-1)).astype(jnp.int32)
    elif episode.choice is None:
        next_view = nbv.choose(episode.policy, views, belief(episode, state), sub, episode.spec.intrinsics,
                               episode.nbv_config)
        next_pose = state.views.T_wc[next_view]
    else:  # a switched episode: the chosen policy's kernel (the index is the same for a vmapped batch)
        kernels = [functools.partial(nbv.choose, episode.nbv_config.policy(p), intrinsics=episode.spec.intrinsics,
                                     config=episode.nbv_config) for p in episode.policies]
        next_view = jax.lax.switch(episode.choice.policy, kernels, views, belief(episode, state), sub)
        next_pose = state.views.T_wc[next_view]
    stop = episode.config.stop
    r = state.refinement
    settled = jnp.any(r.valid) & jnp.all(~r.valid | ((state.stable >= stop.stable_moves)
                                                     & (jnp.max(r.rho, axis=1) >= stop.min_rho)))
    done = (state.observation.frames >= episode.config.moves) | ((stop.stable_moves > 0) & settled)
    return state.replace(next_view=next_view, next_pose=next_pose, done=done, key=key)


STAGES = (("reconstruction", reconstruction), ("segmentation", _perception_stage(observation.segmentation)),
          ("classification", _perception_stage(observation.classification)),
          ("refinement", refinement), ("planning", planning))
MODULES = tuple(name for name, _ in STAGES)  # the per-module times a move records


def check_frame(episode: Episode, depth: np.ndarray | jax.Array, T_wc: np.ndarray | jax.Array) -> None:
    """Host-side validation of a frame (shapes, a rigid finite pose), errors naming what is wrong."""
    observation.check_observation_inputs(episode.spec, depth, T_wc)


def step(episode: Episode, state: EpisodeState, depth: jax.Array, T_wc: jax.Array) -> EpisodeState:
    """One move on the frame (depth [H, W] m, 0 = no return; T_wc [4, 4]) seen from ``state.next_view``:
    fuse, segment, classify, refine, choose the next view. A state already ``done`` comes back unchanged.
    Pure; ``step_jit`` is its module-level jit."""
    new = arrive(episode, state, depth, T_wc)
    # A stopped episode's frame has no returns, so the fusion leaves its volume as it was: the volume (most
    # of the state) is updated in place, not selected between two copies like the other leaves below.
    depth = jnp.where(state.done, 0.0, jnp.asarray(depth, jnp.float32))
    for name, stage in STAGES:
        with jax.named_scope(name):  # the stage's name in XLA's op names: a profile attributes kernels by it
            new = stage(episode, new, depth, T_wc)
    volume = new.observation.volume

    def without_volume(s: EpisodeState) -> EpisodeState:
        return s.replace(observation=s.observation.replace(volume=None))

    kept = jax.tree.map(lambda old, fresh: jnp.where(state.done, old, fresh), without_volume(state),
                        without_volume(new))
    return kept.replace(observation=kept.observation.replace(volume=volume))


step_jit = jax.jit(step)
step_jit.__doc__ = "``step`` under one ``jax.jit`` (compiled once per episode settings and shapes)."


@struct.dataclass
class Trace:
    """What ``rollout`` keeps of each move ([T, ...] stacked): view: the view fused; refinement: the move's
    ``Refinement``; probs: [N, M]; centroid: [N, 3] segment centroids; points: [N] i32 points per segment;
    next_view; tracking: [] i32 the frame's ``tracking.Status``; pose: [4, 4] T_wc it was fused at;
    hand_eye: [4, 4] the hand-eye estimate Y after it (``tracking.HandEye``); done: the move was not made
    (the episode had stopped)."""

    view: jax.Array
    refinement: Refinement
    probs: jax.Array
    centroid: jax.Array
    points: jax.Array
    next_view: jax.Array
    tracking: jax.Array
    pose: jax.Array
    hand_eye: jax.Array
    done: jax.Array


def trace(state: EpisodeState, view: jax.Array, skipped: jax.Array | bool = False) -> Trace:
    """The ``Trace`` of the move to ``view`` that left ``state``; ``skipped``: it was not made (stopped)."""
    obs = state.observation
    return Trace(view=view, refinement=state.refinement, probs=obs.probs, centroid=centroids(obs),
                 points=jnp.sum(obs.segments.mask, axis=1).astype(jnp.int32), next_view=state.next_view,
                 tracking=obs.tracking.status, pose=obs.tracking.pose, hand_eye=obs.tracking.hand_eye.eye,
                 done=jnp.asarray(skipped, bool))


def rollout(episode: Episode, state: EpisodeState, depth: jax.Array, T_wc: jax.Array,
            scene: jax.Array | None = None) -> tuple[EpisodeState, Trace]:
    """A whole episode on frames in memory: depth [V, H, W] and T_wc [V, 4, 4] of every viewpoint (a
    dataset scene), ``episode.config.moves`` moves under one ``lax.scan``. Returns the final state and the
    per-move ``Trace``. ``rollout_jit`` is its jit; vmap it over episodes with ``in_axes=(None, 0, None,
    None)`` (one scene, many starts) or ``(None, 0, 0, 0)``. With ``scene`` ([] i32), depth [S, V, H, W] and
    T_wc [S, V, 4, 4] hold S scenes and the episode reads scene ``scene``'s frames: vmapped over episodes
    of several scenes (``in_axes=(None, 0, None, None, 0)``), each move gathers only its own frame. Not with
    ``off_grid`` (frames off the fixed viewpoints must be rendered)."""
    if episode.config.off_grid:
        raise ValueError("episode: off_grid views are rendered on demand; rollout indexes frames in memory "
                         "(use runner.run with a sources.Rendered source)")

    def frame(view: jax.Array) -> tuple[jax.Array, jax.Array]:
        if scene is None:
            return depth[view], T_wc[view]
        return depth[scene, view], T_wc[scene, view]

    def body(state, _):
        skipped = state.done
        view = state.next_view
        state = step(episode, state, *frame(view))
        return state, trace(state, view, skipped)

    return jax.lax.scan(body, state, None, length=episode.config.moves)


rollout_jit = jax.jit(rollout)
rollout_jit.__doc__ = "``rollout`` under one ``jax.jit``."


_STAGE_JITS = {name: jax.jit(fn) for name, fn in STAGES}
_arrive_jit = jax.jit(arrive)


def timed_step(episode: Episode, state: EpisodeState, depth: jax.Array, T_wc: jax.Array, clock=None
               ) -> tuple[EpisodeState, dict[str, float]]:
    """``step`` run stage by stage from the host, each stage jitted on its own and waited for, so that
    each module's time (ms, ``MODULES``) is measured outside jit. Same result as ``step``."""
    clock = clock or time.perf_counter
    if bool(state.done):
        return state, dict.fromkeys(MODULES, 0.0)
    state = _arrive_jit(episode, state, depth, T_wc)
    times = {}
    for name, stage in _STAGE_JITS.items():
        t0 = clock()
        state = stage(episode, state, depth, T_wc)
        jax.block_until_ready(state)
        times[name] = (clock() - t0) * 1e3
    return state, times


__all__ = [
    "MODULES",
    "STAGES",
    "Choice",
    "Decision",
    "Episode",
    "EpisodeConfig",
    "EpisodeState",
    "StopConfig",
    "Trace",
    "belief",
    "candidate_utilities",
    "centroids",
    "check_frame",
    "empty_refinement",
    "gather_evidence",
    "planned_views",
    "reset",
    "rollout",
    "rollout_jit",
    "seen_from",
    "step",
    "step_jit",
    "timed_step",
    "trace",
]
