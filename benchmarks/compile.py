"""``jaxcls demo`` end to end with the persistent compilation cache off, cold (an empty folder) and warm.

    python benchmarks/compile.py [--rounds 2] [--out BENCHMARKS.md] [demo overrides ...]

Each round runs the demo three times, each in a fresh process: ``JAXCLS_CACHE_DIR=off``; a new empty
folder (cold: every program compiled and written); the same folder again (warm: loaded). The order of the
off and cold runs alternates by round. Reported per setting: the median wall time of the process, the
programs it needed (JAX's ``backend_compile`` events, which count cache loads too) and those loaded; and
whether every run's move records (labels, views, rho; times aside) are the same: the cache changes how a
program is obtained, not what it computes.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from jaxcls import compile_cache, report

# The demo in a child process, counting compilations and cache hits through JAX's monitoring events.
CHILD = """
import json, sys, jax
counts = {"compiled": 0, "hits": 0}
def duration(name, secs, **kw):
    counts["compiled"] += "backend_compile" in name
def event(name, **kw):
    counts["hits"] += "cache_hits" in name
jax.monitoring.register_event_duration_secs_listener(duration)
jax.monitoring.register_event_listener(event)
from jaxcls.cli import main
code = main(["demo", *sys.argv[1:]])
print("COUNTS " + json.dumps(counts))
sys.exit(code)
"""


def _demo(cache: str, out_dir: Path, overrides: list[str]) -> dict:
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", CHILD, f"out_dir={out_dir}", "--overwrite", *overrides],
                          capture_output=True, text=True, env={**os.environ, compile_cache.ENV: cache})
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"jaxcls demo failed ({done.returncode}): {done.stderr[-2000:]}")
    counts = json.loads(next(line for line in done.stdout.splitlines() if line.startswith("COUNTS "))[7:])
    log = json.loads((out_dir / "episode.json").read_text())
    moves = [{k: v for k, v in move.items() if k != "times_ms"} for move in log["moves"]]  # labels, views, rho
    return {"wall": wall, **counts, "moves": moves}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--out", help="append the section to this Markdown file")
    parser.add_argument("overrides", nargs="*", help="jaxcls demo overrides (key=value)")
    args = parser.parse_args(argv)
    runs: dict[str, list[dict]] = {"off": [], "cold": [], "warm": []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            folder = Path(tmp) / f"cache{r}"
            first = ("off", "cold") if r % 2 == 0 else ("cold", "off")
            for setting in (*first, "warm"):
                cache = "off" if setting == "off" else str(folder)
                runs[setting].append(_demo(cache, Path(tmp) / f"demo_{setting}_{r}", args.overrides))
                print(setting, r, {k: v for k, v in runs[setting][-1].items() if k != "moves"}, file=sys.stderr)
    same = all(run["moves"] == runs["off"][0]["moves"] for rs in runs.values() for run in rs)
    rows = []
    for setting, rs in runs.items():
        walls = [run["wall"] for run in rs]
        rows.append((setting, f"{np.median(walls):.1f}", f"{min(walls):.1f}-{max(walls):.1f}",
                     int(np.median([run["compiled"] for run in rs])), int(np.median([run["hits"] for run in rs]))))
    report.publish(report.section(
        f"`jaxcls demo` with the compilation cache off, cold and warm, {report.cpu_name()}", argv,
        ("cache", "wall s (median)", "range", "programs (compiled or loaded)", "loaded from the cache"), rows,
        intro=f"{args.rounds} rounds; each run a fresh process; off and cold alternate, warm follows cold.",
        notes=[f"the demo's move records are {'the same' if same else 'NOT the same'} in every run"]),
        args.out)


if __name__ == "__main__":
    main()
