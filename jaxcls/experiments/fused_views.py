"""PointNetFull against the number of views fused, with the camera poses the sensor reports and the true ones
(``experiments/fused_views.py`` is its command line).

For each scene of a Table 1 config, ``subsets`` seeded random subsets of k views (one subset when k is every
view) are fused and the row's last move (segmentation, classification, GR) runs on them, once with the poses
the episodes see (``T_wc``) and once with the true poses (``T_wc_true``); with tracking on, the views are
fused ``passes`` times (``protocol.all_views``). Each record carries its frames' pose errors.
"""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np
from scipy.spatial.transform import Rotation
from tqdm.auto import tqdm

from jaxcls import io, report
from jaxcls.episode import protocol, scoring, setup, sources
from jaxcls.experiments.table1 import runner
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.experiments.table1.scoring import row_scores
from jaxcls.world.dataset import DatasetConfig
from jaxcls.world.objects import object_set_from_config

POSES = ("reported", "true")


def subset(seed: int, scene: int, k: int, index: int, num_views: int) -> np.ndarray:
    """[k] distinct views of a scene, seeded by (seed, scene, k, index); every view, in order, if k >= V."""
    if k >= num_views:
        return np.arange(num_views)
    return np.random.default_rng([seed, scene, k, index]).choice(num_views, size=k, replace=False)


def pose_errors(fused: np.ndarray, true: np.ndarray, table_height: float) -> dict[str, list[float]]:
    """Each frame's pose error (fused [K, 4, 4] against true [K, 4, 4] T_wc), rounded for the record:
    translation_mm, how far the frame's error G = fused @ true^-1 moves the scene's centre (5 cm above the
    table's centre: where the objects are, so a rotation about the camera counts by its lever arm);
    rotation_deg, G's angle; relative_mm, the same displacement after the frames' mean error is removed (what
    blurs the fused model: a common offset of every frame moves the model but does not blur it)."""
    centre = np.array([0.0, 0.0, table_height + 0.05, 1.0])
    G = np.asarray(fused, np.float64) @ np.linalg.inv(np.asarray(true, np.float64))
    moved = (G @ centre)[:, :3] - centre[:3]
    rotation = np.degrees(Rotation.from_matrix(G[:, :3, :3]).magnitude())
    relative = np.linalg.norm(moved - moved.mean(axis=0), axis=1)
    return {"translation_mm": np.round(np.linalg.norm(moved, axis=1) * 1e3, 3).tolist(),
            "rotation_deg": np.round(rotation, 4).tolist(), "relative_mm": np.round(relative * 1e3, 3).tolist()}


def record_key(r: dict) -> tuple:
    """A record's identity in the store: (classifier, poses, views, scene, subset, passes)."""
    return r["classifier"], r["poses"], int(r["views"]), int(r["scene"]), int(r["subset"]), r.get("passes", 1)


def run(config: Table1Config, dataset: DatasetConfig, files: list[Path], views_fused: list[int], subsets: int,
        row: protocol.Row, passes: int, store: Path, show_progress: bool = True) -> list[dict]:
    """Every (scene, classifier, k, subset, poses) record not yet in ``store`` (JSONL), appended as it is made;
    returns the store's records of ``passes``."""
    object_set = object_set_from_config(dataset.objects)
    classifiers = {name: setup.load_classifier(path, object_set, f"classifiers.{name}")
                   for name, path in config.classifiers.items()}
    done = {record_key(r) for r in io.read_jsonl(store)}
    episodes = {}
    V = dataset.viewpoints.count
    total = len(files) * len(classifiers) * len(POSES) * sum(1 if k >= V else subsets for k in views_fused)
    with tqdm(total=total, desc="fused views", unit="episode", disable=not show_progress) as bar:
        for s, path in enumerate(files):
            views = sources.dataset_source(path, dataset.objects)
            with np.load(path) as scene:
                poses = {"reported": np.asarray(views.T_wc), "true": scene["T_wc_true"]}
            truth = scoring.Truth.from_scene(views.scene, object_set)
            episode_key = protocol.run_keys(config.seed, s, 1)[0]
            for c, classifier in classifiers.items():
                if c not in episodes:
                    episodes[c] = runner.episode(config, row, classifier, object_set, views.intrinsics,
                                                 views.table_height, dataset.scene.split, name=c)
                for k in views_fused:
                    for i in range(1 if k >= V else subsets):
                        chosen = subset(config.seed, s, k, i, V)
                        for pose in POSES:
                            key = (c, pose, min(k, V), s, i, passes)
                            bar.update()
                            if key in done:
                                continue
                            trace, fused = protocol.all_views(episodes[c], views.depth[chosen], poses[pose][chosen],
                                                              episode_key, passes)
                            order = np.concatenate([chosen[1:], chosen[:1]])  # all_views fuses view 0 last
                            record = protocol.episode_record(jax.device_get(trace), truth, classifier=c, poses=pose,
                                                             views=min(k, V), scene=s, subset=i, run=0, start=-1,
                                                             passes=passes)
                            record["pose_error"] = pose_errors(np.asarray(fused), poses["true"][order],
                                                               views.table_height)
                            io.append_jsonl(store, [record])
    return [r for r in io.read_jsonl(store) if r.get("passes", 1) == passes]


def f1_table(records: list[dict], classifiers, views_fused: list[int], num_views: int, scenes: int, classes: int,
             resamples: int) -> str:
    """F1 of the target objects per classifier, camera-pose source and k, pooled over the first ``scenes``
    scenes, with 95% scene-bootstrap intervals (Markdown)."""
    table_rows = []
    for c in classifiers:
        for pose in POSES:
            cells = []
            for k in views_fused:
                recs = [r for r in records if r["classifier"] == c and r["poses"] == pose
                        and r["views"] == min(k, num_views) and r["scene"] < scenes]
                sc = row_scores(recs, classes, 1, resamples)
                cells.append(f"{sc['f1']:.3f} [{sc['f1_low']:.3f}, {sc['f1_high']:.3f}]")
            table_rows.append((c, pose, *cells))
    return report.table(("classifier", "camera poses", *(f"k = {k}" for k in views_fused)), table_rows)


def error_table(records: list[dict], classifiers, views: list[int], num_views: int) -> str:
    """Median and 95th percentile of the frames' pose errors (``pose_errors``) per camera-pose source and k."""
    rows = []
    c = next(iter(classifiers))
    for pose in POSES:
        for name, unit in (("translation_mm", "mm"), ("relative_mm", "mm, mean removed"), ("rotation_deg", "deg")):
            cells = []
            for k in views:
                values = np.concatenate([r["pose_error"][name] for r in records if "pose_error" in r
                                         and r["classifier"] == c and r["poses"] == pose
                                         and r["views"] == min(k, num_views)] or [[np.nan]])
                cells.append(f"{np.median(values):.2f} / {np.percentile(values, 95):.2f}")
            rows.append((pose, f"{name.split('_')[0]} ({unit})", *cells))
    return report.table(("camera poses", "error", *(f"k = {k}" for k in views)), rows)
