"""Table 1 as the paper lays it out (Markdown, per classifier, then the paired differences and the module
times), and every row x move as CSV."""

from __future__ import annotations

import csv
import io as _io
from collections.abc import Sequence
from typing import Any

import numpy as np

from jaxcls import report
from jaxcls.episode import active, protocol
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.experiments.table1.scoring import STATISTICS, differences, row_scores

# The paper's averaged processing time between consecutive moves (Sec. 5, an i7 desktop), ms.
PAPER_TIMES_MS = {"reconstruction": 120, "segmentation": 60, "refinement": 880, "planning": 190}


def tables(config: Table1Config, records: list[dict[str, Any]], classes: int, timing: dict | None,
           argv: Sequence[str] | None) -> tuple[str, list[dict[str, Any]], dict[str, dict[str, list]]]:
    """(Markdown, CSV rows, curves for Figure 4) of the stored episodes."""
    T = config.moves
    half = max(1, T // 2)
    by: dict[tuple[str, str], list[dict]] = {}
    for r in records:
        by.setdefault((r["classifier"], r["row"]), []).append(r)
    sections, csv_rows, curves = [], [], {}
    for c in config.classifiers:
        table_rows, notes, labels = [], [], {}
        curves[c] = {}
        for name in config.rows:
            recs = by.get((c, name), [])
            if not recs:
                continue
            row = protocol.ROWS[name]
            moves = T if row.kind in (protocol.Kind.POLICY, protocol.Kind.ORACLE) else 1
            labels[name] = protocol.scene_labels(recs)
            per_move = row_scores(recs, classes, range(1, moves + 1), config.resamples, labels[name])
            for t, sc in enumerate(per_move, 1):
                csv_rows.append({"classifier": c, "row": name, "label": row.label, "move": t, **sc})
            curves[c][row.label] = per_move
            last = per_move[-1]
            mid = per_move[min(half, moves) - 1]["f1"]
            steps, right = protocol.moves_to_correct(recs, labels=labels[name])
            table_rows.append((row.label, *(f"{last[k]:.3f}" for k in STATISTICS),
                               f"[{last['f1_low']:.3f}, {last['f1_high']:.3f}]", f"{mid:.3f}",
                               f"{steps:.2f}" if moves > 1 else "-", f"{right:.2f}", last["scenes"], last["episodes"],
                               *detections(recs, classes, moves, config.resamples)))
        notes += differences(config, by, c, classes, labels)
        sections.append(report.table(
            ("method", "accuracy", "precision", "recall", "F1", "F1 95% CI (scenes)", f"F1 after {half} moves",
             "moves to correct", "share right at the end", "scenes", "episodes", "F1, phantoms counted",
             "segments - objects"), table_rows))
        sections[-1] = f"#### Classifier `{c}` ({config.classifiers[c] or 'shipped weights'})\n\n" + sections[-1] \
            + ("\n\n" + "\n".join(f"- {n}" for n in notes) if notes else "")
    timing_md = "\n\n" + timing_table(timing) if timing else ""
    intro = (f"{len({r['scene'] for r in records})} scenes of `{config.dataset}`, {config.runs} runs per scene "
             f"from seeded random start views (the same for every row), T = {T}; scores of the target objects "
             f"after move T (PointNetSingle: its one view; PointNetFull: every view fused), pooled over scenes, "
             f"macro over classes; intervals resample whole scenes ({config.resamples} resamples).")
    markdown = (f"### Table 1 on `{config.dataset}`\n\n`{report.command_line(argv)}`\n\n{intro}\n\n"
                + "\n\n".join(sections) + timing_md + "\n")
    return markdown, csv_rows, curves


def detections(records: list[dict[str, Any]], classes: int, moves: int, resamples: int) -> tuple[str, str]:
    """(F1 at the row's last move with each phantom segment a false positive of its class, and its scene-bootstrap
    interval; the mean count error, live segments - the scene's objects, and its mean absolute value), or "-"
    for records stored before they kept their phantoms."""
    if not records or any("phantom" not in r for r in records):
        return "-", "-"
    scores = row_scores(records, classes, moves, resamples, protocol.scene_labels(records, phantoms=True))
    error = np.array([r["segments"][-1] - r["objects"] for r in records], np.float64)
    return (f"{scores['f1']:.3f} [{scores['f1_low']:.3f}, {scores['f1_high']:.3f}]",
            f"{error.mean():+.2f} (abs {np.abs(error).mean():.2f})")


def timing_table(timing: dict) -> str:
    """The module times of ``runner.time_modules`` beside the paper's (Markdown)."""
    times = timing["times_ms"]
    return report.table(
        ("module", f"ours, ms per move ({timing['device']})", "the paper, ms (i7 desktop)"),
        [(m, f"{times[m]:.1f}", f"{PAPER_TIMES_MS[m]}" if m in PAPER_TIMES_MS else "not given")
         for m in active.MODULES] + [("total", f"{sum(times.values()):.1f}", "1250")])


def csv_text(csv_rows: list[dict[str, Any]]) -> str:
    """Every row x move of ``tables`` as CSV text (a header only when there are none)."""
    buffer = _io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(csv_rows[0]) if csv_rows else ["row"])
    writer.writeheader()
    writer.writerows(csv_rows)
    return buffer.getvalue()
