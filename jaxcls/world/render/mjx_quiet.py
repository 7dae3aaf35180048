"""MJX, imported without the lines it prints where warp-lang is absent.

``mujoco.mjx.warp`` prints "Failed to import warp: ..." and "Failed to import mujoco_warp: ..." on import
when warp-lang is not installed: noise on any machine that renders with ``mujoco`` or ``mjx`` (a CUDA
machine without MuJoCo Warp included). ``render.warp.warp_unavailable_reason`` says it in words where it
matters (``backend=warp`` asked for). Every other line MJX prints still reaches stdout.
"""

from __future__ import annotations

import contextlib
import io
import sys

_NOISE = ("Failed to import warp:", "Failed to import mujoco_warp:")

with contextlib.redirect_stdout(io.StringIO()) as _printed:
    import mujoco.mjx.warp as mjxw
    from mujoco import mjx

for _line in _printed.getvalue().splitlines():
    if not _line.startswith(_NOISE):
        print(_line, file=sys.stdout)

__all__ = ["mjx", "mjxw"]
