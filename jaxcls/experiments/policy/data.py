"""The oracle's labels of the states a DAgger round visits: at every decision after the first move, the network's
input (``learned.features``) and each candidate's true F1 after the move (``protocol.oracle_rollouts``)."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxcls import io
from jaxcls.episode import active, protocol, scoring
from jaxcls.planning import learned


@dataclasses.dataclass(frozen=True)
class Decisions:
    """D decisions: the network's input (``learned.Features`` with [D, ...] leaves: pair [D, C, N, P], live [D, N],
    candidate [D, C, F]), f1 [D, C] each candidate's true F1 after the move (-1 where not allowed), allowed [D, C]
    bool the candidates the oracle ranks (unvisited within the radius first), scene [D] int32 the scene each
    decision is of (``collect``: the index into its frames; ``jaxcls train-policy``: into the training draw; -1
    where unknown: a file written before decisions carried it)."""

    features: learned.Features
    f1: np.ndarray
    allowed: np.ndarray
    scene: np.ndarray

    def __len__(self) -> int:
        return len(self.f1)

    @staticmethod
    def concatenate(parts: list[Decisions]) -> Decisions:
        """The decisions of ``parts`` one after the other (none: ValueError)."""
        if not parts:
            raise ValueError("Decisions.concatenate: no decisions")
        return jax.tree.map(lambda *xs: np.concatenate(xs), *parts)

    def save(self, path: str | Path) -> Path:
        """One ``.npz``, written atomically."""
        import io as bytes_io

        buffer = bytes_io.BytesIO()
        np.savez(buffer, pair=self.features.pair, live=self.features.live, candidate=self.features.candidate,
                 f1=self.f1, allowed=self.allowed, scene=self.scene)
        return io.write_bytes(path, buffer.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> Decisions:
        """The decisions ``save`` wrote (``scene`` -1 where the file has none)."""
        with np.load(path) as f:
            scene = f["scene"] if "scene" in f.files else np.full(len(f["f1"]), -1, np.int32)
            return cls(learned.Features(pair=f["pair"], live=f["live"], candidate=f["candidate"]), f["f1"],
                       f["allowed"], scene)

    def split(self, held_out: np.ndarray) -> tuple[Decisions, Decisions]:
        """(the decisions of scenes not in ``held_out``, those of scenes in it): a split by scene, so that no scene
        gives decisions to both. ValueError where a decision's scene is unknown (-1)."""
        if np.any(self.scene < 0):
            raise ValueError("Decisions.split: some decisions do not say their scene (collected by an older jaxcls); "
                             "collect them again (a new out_dir)")
        out = np.isin(self.scene, held_out)
        return jax.tree.map(lambda a: a[~out], self), jax.tree.map(lambda a: a[out], self)


jax.tree_util.register_dataclass(Decisions, data_fields=["features", "f1", "allowed", "scene"], meta_fields=[])


@functools.partial(jax.jit, static_argnames=("layout",))
def _features_of_runs(episode: active.Episode, states: active.EpisodeState, index: jax.Array, ok: jax.Array,
                      layout: learned.Layout) -> learned.Features:
    """[R] runs' network input in ``layout`` at their candidates ``index``, ``ok`` [R, C] (the planner's views and
    belief)."""
    def one(state, i, o):
        return learned.features(active.planned_views(state), active.belief(episode, state), i, o,
                                episode.spec.intrinsics, episode.nbv_config, layout)

    return jax.vmap(one)(states, index, ok)


@jax.jit
def _picks(weights: dict, x: learned.Features, allowed: jax.Array) -> jax.Array:
    """[R] the network's best allowed candidate of each run."""
    return jnp.argmax(jnp.where(allowed, learned.apply(weights, x), -jnp.inf), axis=-1)


def collect(episode: active.Episode, depth: np.ndarray, T_wc: np.ndarray, scene: np.ndarray, starts: np.ndarray,
            keys: jax.Array, truths: list[scoring.Truth], weights: dict | None = None, follow_oracle: float = 1.0,
            rng: np.random.Generator | None = None, runs_per_call: int = 0,
            label: protocol.Label = protocol.Label.greedy, layout: learned.Layout = learned.Layout.v2) -> Decisions:
    """The oracle's rollouts of runs ``starts`` [R] (keys [R]) of the scenes ``scene`` [R] (frames depth [S, V, H, W],
    T_wc [S, V, 4, 4]; ``truths`` a ``Truth`` per run), labelled at every decision after the first move, in calls of
    ``runs_per_call`` runs (0: all at once; the last call padded with copies of its last run, dropped: one compiled
    shape). Each run goes where the oracle goes with probability ``follow_oracle`` (drawn by ``rng`` per run and
    decision), else to the best allowed candidate by the network ``weights`` (DAgger's mixture; without weights,
    the oracle). ``label``: what a candidate's F1 is (``protocol.Label``: after its move, or at T with the
    episode's own policy taking the moves after it). The decisions' features are in ``layout`` (``weights``' own
    where given)."""
    layout = learned.Layout.of(weights) if weights is not None else learned.Layout(layout)
    rng = rng or np.random.default_rng(0)
    R = len(starts)
    size = runs_per_call or R
    kept: list[Decisions] = []
    for first in range(0, R, size):
        real = min(size, R - first)
        rows = np.concatenate([np.arange(first, first + real), np.full(size - real, first + real - 1)])
        frames = np.asarray(scene, np.int32)[rows]

        def tap(states, index, ok, allowed, f1, pick, real=real, frames=frames) -> np.ndarray:
            x = jax.device_get(_features_of_runs(episode, states, jnp.asarray(index, jnp.int32), jnp.asarray(ok),
                                                 layout))
            labelled = Decisions(x, np.asarray(f1, np.float32), np.asarray(allowed), frames)
            kept.append(jax.tree.map(lambda a: a[:real], labelled))
            if weights is None:
                return pick
            ours = np.asarray(_picks(weights, x, jnp.asarray(allowed)))
            return np.where(rng.random(len(pick)) < follow_oracle, pick, ours)

        protocol.oracle_rollouts(episode, depth, T_wc, starts[rows], np.asarray(keys)[rows], [truths[i] for i in rows],
                                 scene=np.asarray(scene)[rows], tap=tap, label=label)
    return Decisions.concatenate(kept)


__all__ = ["Decisions", "collect"]
