"""The host driver of one episode: frames from a ``ViewSource``, each move run stage by stage with each
module timed outside jit (``active.timed_step``), and a record of every move.

    log = run(episode, source, start=0, key=jax.random.PRNGKey(0), truth=Truth.from_scene(scene, object_set))
    log.moves[-1]["scores"]["refined"]["f1"]

A move's record (JSON-ready): move (1-based), view (fused), next_view (the policy's choice), times_ms per
module (``active.MODULES``), stop (the adaptive stop fired), and per live segment: points, centroid,
prior class and score, candidates with their rho, refined class, model and pose (model-to-world), how many
moves its class has held; tracking: the frame's registration (status ``accepted``, ``refused`` or
``reported``, object pairs, RMS residual in mm, the pose it was fused at, frames accepted and refused so
far, the hand-eye estimate as translation mm and rotation deg). With a ``truth``: the target objects'
scores for the prior and the refined labels, each object's surface coverage, and ``detection``: live segments
against the scene's objects, the phantom segments' classes (live, matched to no object) and the refined F1 with
each phantom a false positive of its class.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from jaxcls import metrics
from jaxcls.episode import active, scoring
from jaxcls.episode.sources import ViewSource
from jaxcls.perception import tracking


@dataclasses.dataclass
class EpisodeLog:
    """One episode: what ran (source, policy, start, classes, model names) and a record per move."""

    source: str
    policy: str
    refinement: bool
    start: int
    classes: tuple[str, ...]
    models: tuple[str, ...]
    moves: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    objects: list[dict[str, Any]] = dataclasses.field(default_factory=list)  # the scene's, if known

    @property
    def path(self) -> list[int]:
        """The views fused, in order."""
        return [m["view"] for m in self.moves]

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def curve(self, label: str = "refined", statistic: str = "f1") -> list[float]:
        """A score over moves (needs a truth): ``label`` "refined" or "prior", ``statistic`` of ``Scores``."""
        return [m["scores"][label][statistic] for m in self.moves if "scores" in m]


def _round(x, digits: int = 4):
    return np.round(np.asarray(x, np.float64), digits).tolist()


def move_record(episode: active.Episode, state: active.EpisodeState, times: dict[str, float],
                truth: scoring.Truth | None = None) -> dict[str, Any]:
    """The record of the move that made ``state`` (see the module docstring)."""
    classes = episode.spec.classifier.classes
    obs, r = state.observation, state.refinement
    probs, valid = np.asarray(obs.probs), np.asarray(r.valid)
    centroid = np.asarray(active.centroids(obs))
    points = np.asarray(obs.segments.mask).sum(axis=1)
    prior, refined = np.asarray(r.prior), np.asarray(r.refined)
    candidates, rho, model = np.asarray(r.candidates), np.asarray(r.rho), np.asarray(r.model)
    stable, pose = np.asarray(state.stable), np.asarray(r.pose)
    segments = [{
        "segment": int(n), "points": int(points[n]), "centroid": _round(centroid[n]),
        "prior": classes[prior[n]], "prior_score": round(float(probs[n, prior[n]]), 4),
        "candidates": [classes[c] for c in candidates[n]], "rho": _round(rho[n]),
        "refined": classes[refined[n]], "model": episode.library.names[model[n]] if model[n] >= 0 else None,
        "pose": _round(pose[n], 5), "stable": int(stable[n])} for n in np.flatnonzero(valid)]
    moves = int(state.moves)
    record = {"move": moves, "view": int(np.asarray(state.path)[moves - 1]), "next_view": int(state.next_view),
              "camera": _round(np.asarray(state.cameras)[moves - 1]), "next_camera": _round(state.next_pose[:3, 3]),
              "stop": bool(state.done) and moves < episode.config.moves,
              "times_ms": {k: round(v, 3) for k, v in times.items()}, "segments": segments}
    record["tracking"] = tracking_record(obs.tracking)
    if truth is not None:
        labels = scoring.object_labels(truth, centroid, valid, np.stack([prior, refined]))
        record["scores"] = {name: dataclasses.asdict(scoring.target_scores(truth, lab, len(classes)))
                            for name, lab in zip(("prior", "refined"), labels, strict=True)}
        record["labels"] = {"prior": labels[0].tolist(), "refined": labels[1].tolist()}
        # Phantoms: live segments that matched no object (target or clutter), false positives of their class.
        taken = set(metrics.match_objects(centroid, valid, truth.centroid).tolist())
        phantom = [int(refined[n]) for n in np.flatnonzero(valid) if n not in taken]
        with_phantoms = metrics.classification_scores(
            np.concatenate([truth.label[truth.target], np.full(len(phantom), -1)]),
            np.concatenate([labels[1][truth.target], np.asarray(phantom, np.int64)]), len(classes))
        record["detection"] = {"segments": int(np.asarray(valid).sum()), "objects": len(truth.label),
                               "phantoms": [classes[c] for c in phantom], "f1": round(with_phantoms.f1, 4)}
        surface = obs.surface
        record["coverage"] = _round(scoring.coverage(truth, np.asarray(surface.points)[np.asarray(surface.mask)]), 3)
    return record


def tracking_record(state: tracking.Tracking) -> dict[str, Any]:
    """The JSON record of a frame's tracking (``tracking.Tracking``)."""
    eye = tracking.pose_error(np.asarray(state.hand_eye.eye))
    return {"status": tracking.Status(int(state.status)).name.lower(), "pairs": int(state.pairs),
            "rms_mm": round(float(state.rms) * 1e3, 3), "pose": _round(state.pose, 5),
            "accepted": int(state.accepted), "refused": int(state.refused),
            "hand_eye": {"translation_mm": round(eye[0], 3), "rotation_deg": round(eye[1], 4)}}


def run(episode: active.Episode, source: ViewSource, start: int, key: jax.Array,
        truth: scoring.Truth | None = None, on_move: Callable[..., None] | None = None) -> EpisodeLog:
    """Run one episode from viewpoint ``start`` of ``source`` until ``episode.config.moves`` moves or the
    adaptive stop; ``on_move(record, state, depth, T_wc)`` after each move (printing, pictures). The
    source's camera and table must be the spec's (ValueError naming both)."""
    if source.intrinsics != episode.spec.intrinsics:
        raise ValueError(f"{source.name}: its camera {source.intrinsics} is not the episode's "
                         f"{episode.spec.intrinsics}")
    if abs(source.table_height - episode.spec.table_height) > 1e-9:
        raise ValueError(f"{source.name}: table height {source.table_height} is not the episode's "
                         f"{episode.spec.table_height}")
    state = active.reset(episode, source.viewpoints, start, key)
    log = EpisodeLog(source=source.name, policy=episode.config.policy, refinement=episode.config.refinement,
                     start=int(start), classes=tuple(episode.spec.classifier.classes),
                     models=tuple(episode.library.names))
    if truth is not None:
        log.objects = [{"name": n, "class": log.classes[c], "target": bool(t), "centroid": _round(x)}
                       for n, c, t, x in zip(truth.names, truth.label, truth.target, truth.centroid, strict=True)]
    off_grid = episode.config.off_grid
    if off_grid and not hasattr(source, "frame_at"):
        raise ValueError(f"{source.name}: episode.off_grid renders views off the fixed viewpoints; this source "
                         "only has its recorded ones (render the scene on demand: source \"\")")
    while not bool(state.done):
        if off_grid:
            T_wc = np.asarray(state.next_pose, np.float64)
            depth = source.frame_at(T_wc, jax.random.fold_in(key, 1000 + int(state.moves)))
        else:
            depth, T_wc = source.frame(int(state.next_view))
        active.check_frame(episode, depth, T_wc)
        state, times = active.timed_step(episode, state, np.asarray(depth, np.float32), np.asarray(T_wc, np.float32))
        record = move_record(episode, state, times, truth)
        log.moves.append(record)
        if on_move is not None:
            on_move(record, state, depth, T_wc)
    return log


def path_length(log: EpisodeLog, viewpoints: np.ndarray) -> float:
    """Metres the camera travelled through the episode's views."""
    from jaxcls import metrics

    return metrics.path_length(np.asarray(viewpoints)[log.path, :3, 3])


def describe(record: dict[str, Any]) -> str:
    """A move's record as a few lines of text (what ``jaxcls run`` prints)."""
    times = "  ".join(f"{k[:5]} {v:.0f}" for k, v in record["times_ms"].items())
    lines = [f"move {record['move']:2d}  view {record['view']:3d} -> next {record['next_view']:3d}   "
             f"ms: {times}  (total {sum(record['times_ms'].values()):.0f})"
             + ("   [adaptive stop]" if record.get("stop") else "")]
    for s in record["segments"]:
        rho = ", ".join(f"{c} {p:.2f}" for c, p in zip(s["candidates"], s["rho"], strict=True))
        lines.append(f"    segment {s['segment']} ({s['points']:4d} pts)  {s['prior']:>12} -> {s['refined']:<12} "
                     f"rho: {rho}")
    if "scores" in record:
        p, r = record["scores"]["prior"], record["scores"]["refined"]
        lines.append(f"    targets: F1 prior {p['f1']:.3f} -> refined {r['f1']:.3f}   accuracy {p['accuracy']:.3f} -> "
                     f"{r['accuracy']:.3f}   coverage {np.mean(record['coverage']):.2f}")
    return "\n".join(lines)


def picture_data(episode: active.Episode, state: active.EpisodeState, depth: np.ndarray, T_wc: np.ndarray
                 ) -> dict[str, Any]:
    """What a move's picture (``viz.episode_move``) needs but the views and classes, from the state as the move
    ends and its frame (depth [H, W] m, T_wc [4, 4]): host arrays, keyword arguments of ``viz.episode_move``."""
    classes = episode.spec.classifier.classes
    seg, r = state.observation.segments, state.refinement
    valid = np.asarray(r.valid)
    refined = [classes[c] for c in np.asarray(r.refined)]
    mask = np.asarray(seg.mask) & valid[:, None]
    points = np.asarray(seg.points)[mask]
    labels = [refined[n] for n in np.nonzero(mask)[0]]
    corners = np.asarray(episode.corners)[np.maximum(np.asarray(r.model), 0)]
    pose = np.asarray(r.pose)
    cuboids = np.einsum("nij,nkj->nki", pose[:, :3, :3], corners) + pose[:, None, :3, 3]
    T_cw = np.linalg.inv(np.asarray(T_wc, np.float64))
    cam = points @ T_cw[:3, :3].T + T_cw[:3, 3]
    intr = episode.spec.intrinsics
    front = cam[:, 2] > 1e-6
    pixels = np.stack(intr.project(cam[front, 0], cam[front, 1], 1.0 / cam[front, 2]), axis=-1)
    return {"depth": np.asarray(depth), "pixels": pixels, "pixel_labels": [lb for lb, f in zip(labels, front,
                                                                                                  strict=True) if f],
            "cuboids": cuboids[valid], "cuboid_labels": [refined[n] for n in np.flatnonzero(valid)],
            "points": points, "point_labels": labels, "path": [int(v) for v in np.asarray(state.path) if v >= 0],
            "chosen": int(state.next_view)}


__all__ = ["EpisodeLog", "describe", "move_record", "path_length", "picture_data", "run"]
