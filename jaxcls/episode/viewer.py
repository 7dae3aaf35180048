"""An episode for a 3-D viewer: every move on a timeline in an ``.rrd`` file of rerun (rerun.io), opened by
``jaxcls view`` in rerun's native viewer, its web viewer (``--web``, headless machines: a URL to open) or a
notebook (``rerun.notebook_show`` on a stream that read the file).

Why rerun: it records to a file that replays anywhere (a run on a GPU machine, viewed on a laptop), with a
timeline to scrub move by move, and the same file opens in its native viewer, in a browser and in a notebook;
viser draws a live scene from a running Python process, which a finished episode no longer has.

What a move logs (timeline ``move``, 1 = the first frame's move), all in the world frame (z up, metres):

    world/camera              the camera's pose (the frame's T_wc) and pinhole (the episode's intrinsics)
    world/camera/depth        the move's depth frame (m)
    world/path                the camera positions visited so far
    world/candidates          the move's candidate viewpoints, coloured and labelled by their utility (Eq. 7,
                              or the policy's own; none for Random); world/next_view: the chosen one
    world/segments/by_segment the fused surface's segment points, a colour per segment
    world/segments/by_class   the same points coloured by the segment's refined class
    world/models              each live segment's aligned model cuboid, labelled with its class and rho
    objects/segment_N/p/CLASS each segment's PointNet probability of each class (scalars over the moves)
    objects/segment_N/rho     its best registration ratio (Eq. 2)
    truth/objects             the scene's true objects (static; hide it in the viewer's entity tree)

The class colours and names come from one annotation context (``world``), so every view agrees. Recorded in
memory and written at the end (``write``): a run that fails leaves no half file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np
from scipy.spatial.transform import Rotation

from jaxcls import io
from jaxcls.episode import active

APPLICATION = "jaxcls"
TIMELINE = "move"
_PALETTE = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189], [140, 86, 75],
                     [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]], np.uint8)


def _boxes(corners: np.ndarray, poses: np.ndarray) -> dict[str, np.ndarray]:
    """Oriented boxes of model-frame ``corners`` [N, 8, 3] under ``poses`` [N, 4, 4]: centres, half sizes,
    quaternions (x, y, z, w)."""
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    centre = np.einsum("nij,nj->ni", poses[:, :3, :3], (lo + hi) / 2) + poses[:, :3, 3]
    return {"centers": centre, "half_sizes": (hi - lo) / 2,
            "quaternions": Rotation.from_matrix(poses[:, :3, :3]).as_quat()}


def layout():
    """The viewer's opening layout: the 3-D scene (world and truth) large, the depth frame beside it, the class
    probabilities and rho below."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(rrb.Horizontal(
        rrb.Spatial3DView(origin="/", contents=["/world/**", "/truth/**", "- /world/camera/depth"], name="scene"),
        rrb.Vertical(rrb.Spatial2DView(origin="/world/camera", contents="/world/camera/**", name="depth frame"),
                     rrb.TimeSeriesView(origin="/objects", name="class probabilities and rho"), row_shares=[1, 1]),
        column_shares=[2, 1]), collapse_panels=True)


class EpisodeRecording:
    """Collects an episode's moves for rerun's viewer. ``classes``: the classifier's classes (class ids);
    ``viewpoints`` [V, 4, 4] the source's; ``scene`` and ``object_set``: the truth layer (optional)."""

    def __init__(self, episode: active.Episode, viewpoints: np.ndarray, classes: tuple[str, ...],
                 scene: Any = None, object_set: Any = None, name: str = "episode") -> None:
        import rerun as rr

        self.rr, self.episode, self.classes = rr, episode, tuple(classes)
        self.viewpoints = np.asarray(viewpoints, np.float64)
        self.stream = rr.RecordingStream(APPLICATION, recording_id=None, send_properties=False)
        self.memory = self.stream.memory_recording()
        self.stream.send_recording_name(name)
        self._path: list[np.ndarray] = []
        colours = {i: _PALETTE[i % len(_PALETTE)] for i in range(len(self.classes))}
        self.stream.log("world", rr.AnnotationContext([rr.AnnotationInfo(id=i, label=c, color=colours[i])
                                                        for i, c in enumerate(self.classes)]), static=True)
        self.stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.stream.send_blueprint(layout())
        if scene is not None and object_set is not None:
            self._truth(scene, object_set)

    def _truth(self, scene: Any, object_set: Any) -> None:
        from jaxcls.world.scenes import scene_models

        models = scene_models(scene, object_set)
        corners = np.stack([np.asarray(m.mesh.bounds, np.float64) for m in models])  # [N, 2, 3]: min and max
        ids = [self.classes.index(o.class_name) if o.class_name in self.classes else -1 for o in scene.objects]
        labels = [o.class_name + ("" if o.target else " (clutter)") for o in scene.objects]
        self.stream.log("truth/objects", self.rr.Boxes3D(**_boxes(corners, scene.object_poses()), labels=labels,
                                                         class_ids=ids), static=True)

    def move(self, record: dict, state: active.EpisodeState, depth: np.ndarray, T_wc: np.ndarray) -> None:
        """Log one move (``runner.run``'s ``on_move`` arguments): the frame, the fused segments, the aligned
        models, the candidates and the chosen next view."""
        rr, stream, episode = self.rr, self.stream, self.episode
        stream.set_time(TIMELINE, sequence=int(record["move"]))
        T_wc = np.asarray(T_wc, np.float64)
        k = episode.spec.intrinsics
        stream.log("world/camera", rr.Transform3D(translation=T_wc[:3, 3], mat3x3=T_wc[:3, :3]))
        stream.log("world/camera", rr.Pinhole(focal_length=[k.fx, k.fy], principal_point=[k.cx, k.cy],
                                              width=k.width, height=k.height, camera_xyz=rr.ViewCoordinates.RDF))
        stream.log("world/camera/depth", rr.DepthImage(np.asarray(depth, np.float32), meter=1.0))
        self._path.append(T_wc[:3, 3])
        stream.log("world/path", rr.LineStrips3D([np.stack(self._path)], colors=[[200, 200, 200]]))

        seg, r = state.observation.segments, jax.device_get(state.refinement)
        valid = np.asarray(r.valid)
        mask = np.asarray(seg.mask) & valid[:, None]
        segment = np.nonzero(mask)[0]
        refined = np.asarray(r.refined)
        points = np.asarray(seg.points)[mask]
        stream.log("world/segments/by_segment", rr.Points3D(points, colors=_PALETTE[segment % len(_PALETTE)],
                                                            radii=0.002))
        stream.log("world/segments/by_class", rr.Points3D(points, class_ids=refined[segment], radii=0.002))
        live = np.flatnonzero(valid)
        rho = np.max(np.asarray(r.rho), axis=1)  # [N]: the best candidate's Eq. 2
        corners = np.asarray(episode.corners)[np.maximum(np.asarray(r.model), 0)]
        if live.size:
            stream.log("world/models", rr.Boxes3D(**_boxes(corners[live], np.asarray(r.pose)[live]),
                                                  class_ids=refined[live],
                                                  labels=[f"{self.classes[refined[n]]} rho {rho[n]:.2f}"
                                                          for n in live]))
        else:
            stream.log("world/models", rr.Clear(recursive=False))
        probs = np.asarray(state.observation.probs)
        for n in live:
            for c, name in enumerate(self.classes):
                stream.log(f"objects/segment_{n}/p/{name}", rr.Scalars([float(probs[n, c])]))
            stream.log(f"objects/segment_{n}/rho", rr.Scalars([float(rho[n])]))

        index, ok, U = (np.asarray(x) for x in jax.device_get(_utilities(episode, state)))
        position = self.viewpoints[index, :3, 3]
        scored = np.isfinite(U)
        top = np.nanmax(np.where(ok & scored, U, np.nan)) if np.any(ok & scored) else 1.0
        shade = np.where(ok & scored, U / (top if top > 0 else 1.0), 0.0)
        colours = np.stack([255 * shade, 80 + 0 * shade, 255 * (1 - shade)], axis=1).astype(np.uint8)
        colours[~ok] = [90, 90, 90]
        labels = [f"view {v}" + (f": U {u:.3f}" if np.isfinite(u) else "") + ("" if good else " (beyond r)")
                  for v, u, good in zip(index, U, ok, strict=True)]
        stream.log("world/candidates", rr.Points3D(position, colors=colours, labels=labels, radii=0.015))
        chosen = int(record["next_view"])
        stream.log("world/next_view", rr.Points3D(self.viewpoints[chosen:chosen + 1, :3, 3], radii=0.03,
                                                  colors=[[255, 215, 0]], labels=[f"next: view {chosen}"]))

    def write(self, path: str | Path) -> Path:
        """The recording so far, written to ``path`` atomically (``io.write_bytes``)."""
        self.stream.flush()
        return io.write_bytes(path, self.memory.drain_as_bytes())


def entity_rows(path: str | Path) -> dict[str, int]:
    """{entity path: rows logged} of an ``.rrd`` as rerun's own reader lists it (``rerun rrd print``), after
    ``rerun rrd verify``; ValueError naming the file where either fails."""
    import re
    import subprocess
    import sys

    for check in (["verify"], ["print", "-v"]):
        done = subprocess.run([sys.executable, "-m", "rerun", "rrd", *check, str(path)], capture_output=True,
                              text=True, check=False)
        if done.returncode:
            raise ValueError(f"{path}: rerun rrd {check[0]} failed: {done.stderr.strip()[-500:]}")
    rows: dict[str, int] = {}
    for n, entity in re.findall(r"with (\d+) rows \([^)]*\) - (/\S+) - data columns", done.stdout):
        rows[entity] = rows.get(entity, 0) + int(n)
    return rows


_utilities = jax.jit(active.candidate_utilities)  # (the episode's settings static: compiled once an episode)


__all__ = ["APPLICATION", "TIMELINE", "EpisodeRecording", "entity_rows", "layout"]
