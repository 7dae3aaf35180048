"""Figure 4: F1 over moves for every row of Table 1, with 95% bands."""

from __future__ import annotations

import io as _io
from pathlib import Path

from jaxcls import io, viz


def figure4(curves: dict[str, dict[str, list[dict]]], path: Path) -> None:
    """F1 against moves for every row, with 95% bands: one panel per classifier (``tables.tables``' curves)."""
    figure = viz.score_curves({c: {label: ([s["f1"] for s in v], [s["f1_low"] for s in v], [s["f1_high"] for s in v])
                                   for label, v in rows.items()} for c, rows in curves.items()})
    buffer = _io.BytesIO()
    figure.savefig(buffer, format="png", dpi=120)
    io.write_bytes(path, buffer.getvalue())
