"""Table 1's scores: a row's statistics after a move, pooled over scenes, with F1's scene-bootstrap interval;
the paired differences between rows that the paper's findings rest on."""

from __future__ import annotations

from typing import Any

import numpy as np

from jaxcls import metrics
from jaxcls.episode import protocol
from jaxcls.experiments.table1.config import Table1Config

STATISTICS = ("accuracy", "precision", "recall", "f1")


def row_scores(records: list[dict[str, Any]], classes: int, move: int, resamples: int,
               labels: protocol.SceneLabels | None = None) -> dict[str, Any]:
    """A row's scores after ``move``: each statistic pooled over scenes, F1's 95% scene-bootstrap interval;
    ``labels``: ``protocol.scene_labels(records)`` where the caller scores several moves."""
    per_scene = (labels or protocol.scene_labels(records)).at(move)
    pooled = metrics.classification_scores(np.concatenate([t for t, _ in per_scene]),
                                           np.concatenate([p for _, p in per_scene]), classes)
    _, low, high = metrics.scene_interval(per_scene, classes, "f1", resamples=resamples)
    return {**{k: getattr(pooled, k) for k in STATISTICS}, "f1_low": low, "f1_high": high,
            "scenes": len(per_scene), "episodes": len(records)}


def differences(config: Table1Config, by: dict, c: str, classes: int,
                labels: dict[str, protocol.SceneLabels] | None = None) -> list[str]:
    """Paired scene-bootstrap differences of F1 at T: GR against none per pair; every policy against
    PointNetSingle; VisOcclHist(GR) against Random(GR); every policy against VisOcclHistGR; the oracle
    against the best policy. ``by``: (classifier, row) -> that row's records; ``labels``: row -> its
    ``protocol.scene_labels`` where the caller has them."""
    T, notes = config.moves, []
    prepared: dict[tuple[str, frozenset | None], protocol.SceneLabels] = {
        (name, None): lab for name, lab in (labels or {}).items()}
    scene_sets: dict[str, set] = {}

    def scenes_of(name, move, keep=None):
        """The row's labels per scene after ``move``, on the scenes ``keep`` only (all if None)."""
        if name not in scene_sets:
            scene_sets[name] = {r["scene"] for r in by.get((c, name), [])}
        key = (name, None if keep is None or keep >= scene_sets[name] else frozenset(keep))
        if key not in prepared:
            prepared[key] = protocol.scene_labels([r for r in by.get((c, name), [])
                                                   if key[1] is None or r["scene"] in key[1]])
        return prepared[key].at(move)

    def diff(a, b, move_a=T, move_b=T):
        # Paired on the scenes both rows have (the oracle runs on fewer; an interrupted run may have more).
        shared = {r["scene"] for r in by[c, a]} & {r["scene"] for r in by[c, b]}
        d, lo, hi = metrics.paired_difference(scenes_of(a, move_a, shared), scenes_of(b, move_b, shared), classes,
                                              resamples=config.resamples)
        sig = "" if lo <= 0 <= hi else " (the interval excludes 0)"
        return f"{protocol.ROWS[a].label} - {protocol.ROWS[b].label}: {metrics.format_difference(d, lo, hi)}{sig}"

    present = [n for n in config.rows if (c, n) in by]
    policies = [n for n in present if protocol.ROWS[n].kind is protocol.Kind.POLICY]
    for n in present:
        if n.endswith("_gr") and n[:-3] in present:
            notes.append("GR: " + diff(n, n[:-3]))
    for n in policies:
        single = "single_gr" if protocol.ROWS[n].refinement else "single"
        if single in present:
            notes.append("Active at T against one view: " + diff(n, single, T, 1))
    for a, b in (("vis_occl_hist", "random"), ("vis_occl_hist_gr", "random_gr")):  # the paper's VisOcclHist >= Random
        if a in present and b in present:
            notes.append("VisOcclHist against Random: " + diff(a, b))
    if "vis_occl_hist_gr" in present:
        notes += ["Against VisOcclHistGR: " + diff(n, "vis_occl_hist_gr") for n in policies
                  if n != "vis_occl_hist_gr"]
    if "oracle_gr" in present and policies:
        best = max(policies, key=lambda n: metrics.classification_scores(
            *map(np.concatenate, zip(*scenes_of(n, T), strict=True)), classes).f1)
        notes.append("Oracle against the best policy: " + diff("oracle_gr", best))
    return notes
