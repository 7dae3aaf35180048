"""Table 1 as the paper lays it out (Markdown, per classifier, then the paired differences and the module
times), and every row x move as CSV."""

from __future__ import annotations

import csv
import dataclasses
import importlib
import io as _io
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from jaxcls import report
from jaxcls.episode import active, protocol
from jaxcls.experiments.table1.config import Table1Config
from jaxcls.experiments.table1.scoring import STATISTICS, differences, row_scores

# The paper's averaged processing time between consecutive moves (Sec. 5, an i7 desktop), ms.
PAPER_TIMES_MS = {"reconstruction": 120, "segmentation": 60, "refinement": 880, "planning": 190}


@dataclasses.dataclass(frozen=True, eq=False)
class RowSummary:
    """One (classifier, row)'s part of the tables (``row_summary``): ``episodes`` the (scene, run) of the records
    it was made of, in their order; ``labels`` their ``protocol.scene_labels``; ``per_move`` the scores after each
    move (``row_scores``); ``cells`` the row's cells of the Markdown table."""

    episodes: tuple[tuple[int, int], ...]
    labels: protocol.SceneLabels
    per_move: list[dict[str, Any]]
    cells: tuple


def episodes_of(records: list[dict[str, Any]]) -> tuple[tuple[int, int], ...]:
    """(scene, run) of each record, in order: what a ``RowSummary`` was made of."""
    return tuple((int(r["scene"]), int(r["run"])) for r in records)


def row_summary(config: Table1Config, name: str, records: list[dict[str, Any]], classes: int) -> RowSummary:
    """A row's scores after every move with their intervals, and its cells of the table, from its ``records``
    (one classifier's; the row's every episode)."""
    row = protocol.ROWS[name]
    T = config.moves
    half = max(1, T // 2)
    moves = T if row.kind in (protocol.Kind.POLICY, protocol.Kind.ORACLE) else 1
    labels = protocol.scene_labels(records)
    per_move = row_scores(records, classes, range(1, moves + 1), config.resamples, labels)
    last, mid = per_move[-1], per_move[min(half, moves) - 1]["f1"]
    steps, right = protocol.moves_to_correct(records, labels=labels)
    cells = (row.label, *(f"{last[k]:.3f}" for k in STATISTICS), f"[{last['f1_low']:.3f}, {last['f1_high']:.3f}]",
             f"{mid:.3f}", f"{steps:.2f}" if moves > 1 else "-", f"{right:.2f}", last["scenes"], last["episodes"],
             *detections(records, classes, moves, config.resamples))
    return RowSummary(episodes=episodes_of(records), labels=labels, per_move=per_move, cells=cells)


def by_row(records: list[dict[str, Any]]) -> dict[tuple[str, str], list[dict[str, Any]]]:
    """(classifier, row) -> its records, in their order."""
    by: dict[tuple[str, str], list[dict]] = {}
    for r in records:
        by.setdefault((r["classifier"], r["row"]), []).append(r)
    return by


@dataclasses.dataclass(frozen=True)
class Early:
    """What ``EarlyRows`` made before the last episodes were stored: ``summaries`` by (classifier, row), and the
    paired differences of those rows (``scoring.differences``' ``made``)."""

    summaries: Mapping[tuple[str, str], RowSummary]
    differences: Mapping[tuple, tuple[float, float, float]]


def tables(config: Table1Config, records: list[dict[str, Any]], classes: int, timing: dict | None,
           argv: Sequence[str] | None, early: Early | None = None
           ) -> tuple[str, list[dict[str, Any]], dict[str, dict[str, list]]]:
    """(Markdown, CSV rows, curves for Figure 4) of the stored episodes. ``early``: rows and differences made
    before (e.g. while the oracle still ran, ``EarlyRows``), used where made of the same episodes in the same
    order (a classifier's differences only where each of its rows made before was)."""
    T = config.moves
    half = max(1, T // 2)
    by = by_row(records)
    sections, csv_rows, curves = [], [], {}
    for c in config.classifiers:
        table_rows, notes, labels = [], [], {}
        curves[c] = {}
        reuse = early is not None  # (the early differences: while every early row of c is of these records)
        for name in config.rows:
            recs = by.get((c, name), [])
            if not recs:
                continue
            summary = early.summaries.get((c, name)) if early is not None else None
            if summary is not None and summary.episodes != episodes_of(recs):
                summary, reuse = None, False
            if summary is None:
                summary = row_summary(config, name, recs, classes)
            row = protocol.ROWS[name]
            labels[name] = summary.labels
            for t, sc in enumerate(summary.per_move, 1):
                csv_rows.append({"classifier": c, "row": name, "label": row.label, "move": t, **sc})
            curves[c][row.label] = summary.per_move
            table_rows.append(summary.cells)
        notes += differences(config, by, c, classes, labels, dict(early.differences) if reuse else None)
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


class EarlyRows:
    """The summaries of the rows whose episodes are all stored and their paired differences, made on a thread
    while the rest still run (``--local-processes``' launcher: every process runs its batched rows before the
    oracle, so those rows' tables are made while the oracle runs; Figure 4's plotting library is loaded there
    too). ``offer(records)``: the records stored so far (every store's, in order), offered as often as
    convenient; ``select``: the records of these that the tables use (e.g. ``data.of_config``); ``result()``:
    what was made (``Early``; waits for the thread)."""

    def __init__(self, config: Table1Config, classes: int, keys: Sequence[tuple[str, str, int, int]],
                 select: Callable[[list[dict[str, Any]]], list[dict[str, Any]]] = list) -> None:
        self._config, self._classes, self._select = config, classes, select
        self._wanted: dict[tuple[str, str], int] = {}  # (classifier, row) -> its episodes
        for c, name, _, _ in keys:
            if protocol.ROWS[name].kind is not protocol.Kind.ORACLE:
                self._wanted[c, name] = self._wanted.get((c, name), 0) + 1
        self._total = sum(self._wanted.values())
        self._summaries: dict[tuple[str, str], RowSummary] = {}
        self._differences: dict[tuple, tuple[float, float, float]] = {}
        self._thread: threading.Thread | None = None

    def offer(self, records: list[dict[str, Any]]) -> None:
        if self._thread is not None or len(records) < self._total:
            return
        by = by_row(self._select(records))
        if any(len(by.get(k, ())) < n for k, n in self._wanted.items()):
            return
        rows = {k: by[k] for k in self._wanted}
        self._thread = threading.Thread(target=self._make, args=(rows,), name="table1-early-rows", daemon=True)
        self._thread.start()

    def _make(self, rows: dict[tuple[str, str], list[dict[str, Any]]]) -> None:
        for (c, name), recs in rows.items():
            self._summaries[c, name] = row_summary(self._config, name, recs, self._classes)
        for c in dict.fromkeys(c for c, _ in rows):
            labels = {name: s.labels for (k, name), s in self._summaries.items() if k == c}
            differences(self._config, rows, c, self._classes, labels, self._differences)
        importlib.import_module("jaxcls.experiments.table1.figure")  # (matplotlib's import, ~0.3 s, off the tail)

    def result(self) -> Early:
        if self._thread is not None:
            self._thread.join()
        return Early(dict(self._summaries), dict(self._differences))


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
