"""Table 1's scores: a row's statistics after a move, pooled over scenes, with F1's scene-bootstrap interval;
the paired differences between rows that the paper's findings rest on."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from jaxcls import metrics
from jaxcls.episode import protocol
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.planning import nbv

STATISTICS = ("accuracy", "precision", "recall", "f1")


def row_scores(records: list[dict[str, Any]], classes: int, move: int | Sequence[int], resamples: int,
               labels: protocol.SceneLabels | None = None) -> dict[str, Any] | list[dict[str, Any]]:
    """A row's scores after ``move``: each statistic pooled over scenes, F1's 95% scene-bootstrap interval;
    ``labels``: ``protocol.scene_labels(records)`` where the caller has them. ``move`` a sequence of moves: a
    list of their scores, every move's interval from one bootstrap (``metrics.scene_intervals``: the bounds
    each alone would get)."""
    moves = [move] if isinstance(move, int) else list(move)
    labels = labels or protocol.scene_labels(records)
    per_move = [labels.at(t) for t in moves]
    intervals = metrics.scene_intervals(per_move, classes, "f1", resamples=resamples)
    scores = []
    for per_scene, (_, low, high) in zip(per_move, intervals, strict=True):
        pooled = metrics.classification_scores(np.concatenate([t for t, _ in per_scene]),
                                               np.concatenate([p for _, p in per_scene]), classes)
        scores.append({**{k: getattr(pooled, k) for k in STATISTICS}, "f1_low": low, "f1_high": high,
                       "scenes": len(per_scene), "episodes": len(records)})
    return scores[0] if isinstance(move, int) else scores


def differences(config: Table1Config, by: dict, c: str, classes: int,
                labels: dict[str, protocol.SceneLabels] | None = None, made: dict | None = None) -> list[str]:
    """Paired scene-bootstrap differences of F1 at T: GR against none per pair; every policy against
    PointNetSingle; VisOcclHist(GR) against Random(GR); every policy against VisOcclHistGR; the oracle
    against the best policy; the learned policy against the best hand-made one, and the oracle against it (the
    pairs of the rows ``by`` has; the oracle against the learned policy only where that is not the best policy,
    else it is the pair before); then the share of each oracle's lead over the best hand-made policy that the
    learned one closes (``metrics.share_of_gap``, on the scenes of all three, where they are 2 or more), and where
    the oracle ran on fewer scenes than the two policies, the share with the learned policy's lead on all of theirs
    (``metrics.share_of_gap_all_scenes``).
    ``by``: (classifier, row) -> that row's records; ``labels``: row -> its ``protocol.scene_labels`` where the
    caller has them. ``made``: the differences made before of the same records (e.g. while the oracle still ran,
    ``tables.EarlyRows``), keyed by (classifier, row a, row b, a's move, b's move, the scenes paired): used where
    present, and given those made here (a pair's interval does not depend on the pairs bootstrapped beside it:
    ``metrics.paired_differences``)."""
    T = config.moves
    prepared: dict[tuple[str, frozenset | None], protocol.SceneLabels] = {
        (name, None): lab for name, lab in (labels or {}).items()}
    scene_sets: dict[str, set] = {}

    def scenes_in(name):
        """The scenes the row has records of."""
        if name not in scene_sets:
            scene_sets[name] = {r["scene"] for r in by.get((c, name), [])}
        return scene_sets[name]

    def scenes_of(name, move, keep=None):
        """The row's labels per scene after ``move``, on the scenes ``keep`` only (all if None)."""
        key = (name, None if keep is None or keep >= scenes_in(name) else frozenset(keep))
        if key not in prepared:
            prepared[key] = protocol.scene_labels([r for r in by.get((c, name), [])
                                                   if key[1] is None or r["scene"] in key[1]])
        return prepared[key].at(move)

    pairs: list[tuple[str, str, str, int, int]] = []  # (the note's prefix, row a, row b, a's move, b's move)
    present = [n for n in config.rows if (c, n) in by]
    policies = [n for n in present if protocol.ROWS[n].kind is protocol.Kind.POLICY]
    for n in present:
        if n.endswith("_gr") and n[:-3] in present:
            pairs.append(("GR: ", n, n[:-3], T, T))
    for n in policies:
        single = "single_gr" if protocol.ROWS[n].refinement else "single"
        if single in present:
            pairs.append(("Active at T against one view: ", n, single, T, 1))
    for a, b in (("vis_occl_hist", "random"), ("vis_occl_hist_gr", "random_gr")):  # the paper's VisOcclHist >= Random
        if a in present and b in present:
            pairs.append(("VisOcclHist against Random: ", a, b, T, T))
    if "vis_occl_hist_gr" in present:
        pairs += [("Against VisOcclHistGR: ", n, "vis_occl_hist_gr", T, T) for n in policies if n != "vis_occl_hist_gr"]
    def best_of(names):
        return max(names, key=lambda n: metrics.classification_scores(
            *map(np.concatenate, zip(*scenes_of(n, T), strict=True)), classes).f1)

    hand_made = [n for n in policies if nbv.PolicyName(protocol.ROWS[n].policy) is not nbv.PolicyName.learned]
    best_policy = best_of(policies) if policies else None
    oracles = [n for n in present if protocol.ROWS[n].kind is protocol.Kind.ORACLE] if policies else []
    pairs += [("Oracle against the best policy: ", o, best_policy, T, T) for o in oracles]
    best_hand_made = best_of(hand_made) if "learned_gr" in present and hand_made else None
    if best_hand_made:  # (issue 37: half the gap best hand-made -> oracle)
        pairs.append(("The learned policy against the best hand-made one: ", "learned_gr", best_hand_made, T, T))
        if best_policy != "learned_gr":  # (else the oracle against the best policy is that pair)
            pairs += [("Oracle against the learned policy: ", o, "learned_gr", T, T) for o in oracles]
    # Paired on the scenes both rows have (the oracle runs on fewer; an interrupted run may have more); the pairs of
    # one scene set in one bootstrap (``metrics.paired_differences``: the bounds each alone would get).
    shared = [frozenset({r["scene"] for r in by[c, a]} & {r["scene"] for r in by[c, b]}) for _, a, b, _, _ in pairs]
    made = {} if made is None else made
    keys = [(c, a, b, ta, tb, scenes) for (_, a, b, ta, tb), scenes in zip(pairs, shared, strict=True)]
    for scenes in dict.fromkeys(shared):
        at = [i for i, sc in enumerate(shared) if sc == scenes and keys[i] not in made]
        found = metrics.paired_differences(
            [(scenes_of(pairs[i][1], pairs[i][3], scenes), scenes_of(pairs[i][2], pairs[i][4], scenes)) for i in at],
            classes, resamples=config.resamples)
        for i, r in zip(at, found, strict=True):
            made[keys[i]] = r
    results = [made[k] for k in keys]
    notes = []
    for (prefix, a, b, _, _), (d, lo, hi) in zip(pairs, results, strict=True):
        sig = "" if lo <= 0 <= hi else " (the interval excludes 0)"
        notes.append(f"{prefix}{protocol.ROWS[a].label} - {protocol.ROWS[b].label}: "
                     f"{metrics.format_difference(d, lo, hi)}{sig}")
    def shown(share, base):
        """A share with its interval, and why it is infinite where it is."""
        estimate, low, high = map(format_share, share)
        why = f" (+inf: the oracle does not lead {base} there)" if "inf" in estimate + low + high else ""
        return f"{estimate} [{low}, {high}]{why}"

    for o in oracles if best_hand_made else ():  # the share of the oracle's lead the learned policy closes
        three = ("learned_gr", best_hand_made, o)
        scenes = set.intersection(*(scenes_in(n) for n in three))
        if len(scenes) < 2:  # (no interval)
            continue
        share = metrics.share_of_gap(*(scenes_of(n, T, scenes) for n in three), classes, resamples=config.resamples)
        ours, a, b = (protocol.ROWS[n].label for n in three)
        notes.append(f"The share of the oracle's lead the learned policy closes: ({ours} - {a}) / ({b} - {a}) on the "
                     f"{len(scenes)} scenes of all three: {shown(share, a)}")
        wide = scenes_in("learned_gr") & scenes_in(best_hand_made)
        if wide > scenes:  # (the oracle on fewer scenes: the learned policy's lead on all of them, too)
            inside = np.isin(sorted(wide), sorted(scenes))  # (scene_labels' order: by scene)
            share = metrics.share_of_gap_all_scenes(
                scenes_of("learned_gr", T, wide), scenes_of(best_hand_made, T, wide), scenes_of(o, T, scenes),
                scenes_of(best_hand_made, T, scenes), inside, classes, resamples=config.resamples)
            notes.append(f"The same share with the learned policy's lead over {a} on all {len(wide)} scenes, the "
                         f"oracle's on its {len(scenes)} (metrics.share_of_gap_all_scenes): {shown(share, a)}")
    return notes


def format_share(x: float) -> str:
    """A share at two decimals; beyond +-1,000 +-inf (+inf: the oracle does not lead the base,
    ``metrics.SHARE_UNDEFINED``; a percentile between that and a share is no share either)."""
    return f"{x:+.2f}" if abs(x) < 1e3 else ("+inf" if x > 0 else "-inf")
