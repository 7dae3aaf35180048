"""What the 3-D recording costs ``jaxcls demo``: the demo with ``rerun=false`` against ``rerun=true`` (its
``episode.rrd``), each in a fresh process with the compilation cache warm, interleaved.

    python benchmarks/viewer.py [--rounds 3] [--out BENCHMARKS.md] [demo overrides ...]

A first run fills a fresh cache (both variants' programs); then each round runs the two variants, the order
alternating by round. Reported: the median wall time of each (and its range), the cost of the recording, the
.rrd's size and its size per move.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from jaxcls import compile_cache, report


def _demo(cache: str, out_dir: Path, rerun: bool, overrides: list[str]) -> float:
    env = {**os.environ, compile_cache.ENV: cache}
    began = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "jaxcls.cli", "demo", f"rerun={str(rerun).lower()}",
                           f"out_dir={out_dir}", "--overwrite", *overrides], env=env, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"demo failed ({done.returncode}): {done.stderr[-2000:]}")
    return time.perf_counter() - began


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--out", help="append the table to this Markdown file")
    args, overrides = parser.parse_known_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        cache, out = str(Path(tmp) / "xla"), Path(tmp) / "runs"
        for rerun in (True, False):  # fill the cache
            _demo(cache, out / "warm-up", rerun, overrides)
        times: dict[bool, list[float]] = {True: [], False: []}
        for r in range(args.rounds):
            for rerun in ((False, True) if r % 2 == 0 else (True, False)):
                times[rerun].append(_demo(cache, out / f"{rerun}-{r}", rerun, overrides))
                print(f"round {r + 1}: rerun={rerun}: {times[rerun][-1]:.1f} s", flush=True)
        rrd = out / f"True-{args.rounds - 1}" / "episode.rrd"
        moves = len(__import__("json").loads((rrd.parent / "episode.json").read_text())["moves"])
        size = rrd.stat().st_size
    base, with_rrd = float(np.median(times[False])), float(np.median(times[True]))
    rows = [(name, report.device_name(), f"{np.median(t):.1f}", f"{min(t):.1f}-{max(t):.1f}")
            for name, t in (("rerun=false", times[False]), ("rerun=true (episode.rrd)", times[True]))]
    report.publish(report.section(
        "`jaxcls demo` with and without its 3-D recording", sys.argv[1:] if argv is None else argv,
        ("demo", "device", "median wall s (warm cache)", "range"), rows,
        intro=f"Each run a fresh process, the compilation cache warm, {args.rounds} interleaved rounds. The "
              f"recording costs {with_rrd - base:+.1f} s ({100 * (with_rrd / base - 1):+.1f}%); episode.rrd: "
              f"{size / 1e6:.2f} MB for {moves} moves ({size / moves / 1e3:.0f} kB a move)."), args.out)


if __name__ == "__main__":
    main()
