"""Markdown output of benchmark and experiment scripts: every table carries the command that made it."""

from __future__ import annotations

import os
import platform
import shlex
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path


def command_line(argv: Sequence[str] | None = None) -> str:
    """The command that ran this script, as a reader would retype it (``argv`` as given to ``main``)."""
    args = sys.argv[1:] if argv is None else list(argv)
    return "python " + " ".join(shlex.quote(a) for a in [sys.argv[0], *args])


def publish(markdown: str, out: str | Path | None = None) -> None:
    """Print a Markdown section and, with ``out``, append it to that file (BENCHMARKS.md, RESULTS.md)."""
    print(markdown)
    if out:
        with open(out, "a") as f:
            f.write("\n" + markdown)


def table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A Markdown table (no trailing newline)."""
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join("---" for _ in header) + " |"]
    return "\n".join(lines + ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows])


def section(title: str, argv: Sequence[str] | None, header: Sequence[str], rows: Sequence[Sequence[object]],
            intro: str = "", notes: Sequence[str] = ()) -> str:
    """A Markdown section: ``### title``, the command that made it, an optional intro, the table, notes."""
    lines = [f"### {title}", "", f"`{command_line(argv)}`", ""]
    if intro:
        lines += [intro, ""]
    lines.append(table(header, rows))
    if notes:
        lines += ["", *[f"- {note}" for note in notes]]
    return "\n".join(lines) + "\n"


def timed(fn: Callable[[], object], repeats: int) -> tuple[float, float, object]:
    """(first-call seconds, median seconds of ``repeats`` later calls, last result), waiting for JAX's
    asynchronous results (``block_until_ready``); the first call includes compilation."""
    import jax

    start = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return first, statistics.median(times), out


def interleaved(contenders: dict[str, Callable[[], object]], repeats: int) -> tuple[dict[str, list[float]], dict]:
    """Each contender (name: a call of nothing) run ``repeats`` rounds, round-robin, waiting for JAX's asynchronous
    results: ({name: its seconds a round}, {name: its last result}). A/B comparisons in one process."""
    import jax

    times: dict[str, list[float]] = {name: [] for name in contenders}
    results = {}
    for _ in range(repeats):
        for name, run in contenders.items():
            start = time.perf_counter()
            results[name] = jax.block_until_ready(run())
            times[name].append(time.perf_counter() - start)
    return times, results


def process_age() -> float | None:
    """Seconds since this process started (Linux's /proc; None elsewhere): what Python and the imports took
    before a script's first line of work."""
    try:
        start_ticks = int(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])
        uptime = float(Path("/proc/uptime").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return max(0.0, uptime - start_ticks / os.sysconf("SC_CLK_TCK"))


def cpu_name() -> str:
    """This machine's CPU as the tables name it: ``CPU (x86_64, 2 cores)``."""
    return f"CPU ({platform.processor() or platform.machine()}, {os.cpu_count()} cores)"


def device_name() -> str:
    """This process's devices as the tables name them (the CPU, or ``GPU (kind)``, ``N x GPU (kind)``; under
    ``jax.distributed`` a process's own, not every host's)."""
    import jax

    local = jax.local_devices()
    d = local[0]
    if d.platform == "cpu":
        return cpu_name()
    return f"GPU ({d.device_kind})" if len(local) == 1 else f"{len(local)} x GPU ({d.device_kind})"
