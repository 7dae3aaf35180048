"""Table 1's warm start: the first batched call of a run whose compilation cache is warm, with JAX's cache alone
against JAX's cache plus the traced programs kept on disk (``compile_cache.exported``).

    python benchmarks/first_call.py [--rounds 3] [--settings jax exported] [--classifiers shipped]
        [--config CONFIG] [--out BENCHMARKS.md] [overrides ...]

Settings: ``jax`` (JAX's cache alone), ``exported`` (plus the exported programs, loaded ahead on up to
``compile_cache.AHEAD_THREADS`` threads at once; where a device renders the frames, the first chunk's made on a
thread while the classifiers load), ``serial`` (the same, one program at a time: the programs of several
classifiers, ``--classifiers shipped paper``, loaded one after the other), ``wait_all`` (``exported`` with the
first call waiting for every classifier's programs, not its own alone: as before 4b244bc), ``frames_later``
(``exported`` with the first frames made after the classifiers load, on the main thread: ``runner.FRAMES_AHEAD``
off), ``frames_ahead`` (``exported`` with them made on a thread wherever the renderer allows work beside its renders:
``runner.FRAMES_AHEAD`` on) and ``import_early`` (``exported`` with MJX and MuJoCo Warp imported when the process
starts, on the main thread, as where choosing the renderer imported them: before 5cd8821), ``devices_thread``
(``exported`` with JAX's runtime started on a thread when the process starts, beside the imports) and
``no_prealloc`` (``exported`` with ``XLA_PYTHON_CLIENT_PREALLOCATE=false``: no pool of 75% of the GPU taken at
the first transfer) and ``full_tracebacks`` (``exported`` with JAX's whole traceback in each operation's location,
JAX's default, not one frame: ``compile_cache.one_frame_locations`` off) and ``classifiers_first`` (``exported``
with every classifier loaded before the first call, not the first call's alone: ``runner.LATER_CLASSIFIERS`` off)
and ``objects_built`` (``exported`` with the procedural object set made in the process, not read back from the
host cache: ``objects.model.kept_on_disk`` off) and ``no_bytecode`` (``exported`` with Python writing no bytecode
and reading it only from the ``__pycache__`` folders beside the sources: ``PYTHONDONTWRITEBYTECODE=1``, no
``PYTHONPYCACHEPREFIX``. Where the environment ships none, as on the GPU machines this project is lent, every such
module is compiled from its source at each import; pip writes them when it installs a package).
Each setting gets its own cache folder, filled by one cold run (or, ``--cache-from DIR``, a copy of a folder an
earlier run of the same config filled: no cold run); then the settings' warm runs take turns (the
order reversed every other round), each a fresh process of ``experiments/table1.py`` (its own ``out_dir``).
Reported per setting: the median of the process's wall time and of its run's phases (``run_times.json``): the
first call (tracing, lowering, compiling or loading the episode program), when it was dispatched (seconds since
the process started: a warm run's start) and the whole run; and whether every run's records are the same. A
second table: a warm run's start step by step (the start-up phase, then the run's marks: devices ready,
classifiers loaded, first frames made, programs loaded, first call dispatched). JAX's cache alone still traces
and lowers the program before its lookup; the exported program skips both. Default config: 2 scenes of the
synthetic set at 320x240, 2 runs of 2 moves of three batched rows (the program is the full switched one whatever
the size).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from jaxcls import compile_cache, report
from jaxcls.experiments.table1 import runner
from jaxcls.experiments.table1.runner import FIRST_CALL, FIRST_CALL_DISPATCHED

# A warm run's start, in the order it comes on a GPU (``run_times.json``: the start-up phase, then the marks).
STARTUP = "start-up (Python, imports, config)"
TIMELINE = (runner.DEVICES_READY, runner.CLASSIFIERS_LOADED, runner.FIRST_FRAMES_MADE, runner.PROGRAMS_LOADED,
            FIRST_CALL_DISPATCHED)

ROOT = Path(__file__).resolve().parents[1]

# experiments/table1.py in a child process; "jax" keeps JAX's cache only (no exported programs).
CHILD = """
import os, runpy, sys, threading
if sys.argv[1] == "no_prealloc":  # (before JAX starts its runtime)
    os.environ["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"
if sys.argv[1] == "full_tracebacks":  # (JAX's whole traceback in each operation's location: JAX's default)
    os.environ["JAX_INCLUDE_FULL_TRACEBACKS_IN_LOCATIONS"] = "true"
if sys.argv[1] == "devices_thread":  # (the runtime started on a thread while the main one imports)
    import jax
    threading.Thread(target=jax.devices, daemon=True).start()
from jaxcls import compile_cache
if sys.argv[1] == "jax":
    compile_cache.exported = lambda jitted, args, kind, options=None: compile_cache.jitted(jitted, options)
if sys.argv[1] == "serial":
    compile_cache.AHEAD_THREADS = 1
if sys.argv[1] == "objects_built":  # (the procedural object set made, not read back from the host cache)
    from jaxcls.world.objects import builtin, lookalike
    builtin.kept_on_disk = lookalike.kept_on_disk = lambda kind, arguments, build: build()
if sys.argv[1] == "classifiers_first":  # (every classifier loaded before the first call, as before)
    from jaxcls.experiments.table1 import runner
    runner.LATER_CLASSIFIERS = False
if sys.argv[1] == "wait_all":  # (every classifier's programs loaded before the first call, as before 4b244bc)
    from jaxcls.experiments.table1 import runner
    run_batched = runner.run_batched

    def waiting_for_all(*args, loading=None, **kwargs):
        if loading:
            first, *rest = loading
            loading = {first: [f for futures in loading.values() for f in futures], **{c: [] for c in rest}}
        return run_batched(*args, loading=loading, **kwargs)

    runner.run_batched = waiting_for_all
if sys.argv[1] == "import_early":  # (MJX and MuJoCo Warp imported before the config is read, as before 5cd8821)
    from jaxcls.world.render import mjx_quiet  # noqa: F401
if sys.argv[1] in ("frames_later", "frames_ahead"):
    from jaxcls.experiments.table1 import runner
    runner.FRAMES_AHEAD = sys.argv[1] == "frames_ahead"
sys.argv = ["experiments/table1.py", *sys.argv[2:]]
runpy.run_path("experiments/table1.py", run_name="__main__")
"""

SMALL = """dataset: synthetic
scene_source: device
runs: 2
moves: 2
timing_moves: 0
scene_chunk: 2
resamples: 100
rows: [single_gr, random_gr, vis_occl_hist_gr]
classifiers: {classifiers}
dataset_overrides: [num_scenes=2, viewpoints.count=12, backend=mujoco, camera.width=320, camera.height=240,
                    camera.fx=262.5, camera.fy=262.5, camera.cx=159.5, camera.cy=119.5, out_dir={data}]
"""


SETTINGS = {"jax": "JAX's cache",
            "exported": f"JAX's cache + the exported programs (up to {compile_cache.AHEAD_THREADS} loads at once; "
                        "the first frames made while the classifiers load where a device renders them)",
            "serial": "JAX's cache + the exported programs, loaded one at a time",
            "wait_all": "JAX's cache + the exported programs, the first call waiting for every classifier's",
            "frames_later": "JAX's cache + the exported programs, the first frames made after the classifiers load",
            "frames_ahead": "JAX's cache + the exported programs, the first frames made while the classifiers load",
            "import_early": "JAX's cache + the exported programs, MJX and MuJoCo Warp imported at the start",
            "devices_thread": "JAX's cache + the exported programs, the runtime started on a thread at the start",
            "no_prealloc": "JAX's cache + the exported programs, no preallocated GPU memory pool",
            "full_tracebacks": "JAX's cache + the exported programs, whole tracebacks in the locations",
            "classifiers_first": "JAX's cache + the exported programs, every classifier loaded before the first call",
            "objects_built": "JAX's cache + the exported programs, the object set made, not read back",
            "no_bytecode": "JAX's cache + the exported programs, no bytecode written (only what ships read)"}
CLASSIFIERS = {"shipped": "", "paper": "builtin_paper"}


def _run(setting: str, cache: Path, config: str, out: Path, overrides: list[str]) -> dict:
    env = {**os.environ, compile_cache.ENV: str(cache)}
    if setting == "no_bytecode":  # (read before the interpreter starts)
        env.pop("PYTHONPYCACHEPREFIX", None)
        env["PYTHONDONTWRITEBYTECODE"] = "1"
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", CHILD, setting, "--config", config, f"out_dir={out}", *overrides],
                          capture_output=True, text=True, cwd=ROOT, env=env)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"experiments/table1.py failed ({done.returncode}): {done.stderr[-2000:]}")
    phases = json.loads((out / "run_times.json").read_text())[-1]
    records = sorted((json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()),
                     key=lambda r: (r["classifier"], r["row"], r["scene"], r["run"]))
    return {"wall": wall, "first": phases["phases_s"].get(FIRST_CALL, 0.0), "run": phases["total_s"],
            "started": phases.get("marks_s", {}).get(FIRST_CALL_DISPATCHED, float("nan")), "records": records,
            "timeline": {STARTUP: phases["phases_s"].get(STARTUP, float("nan")),
                         **{m: phases.get("marks_s", {}).get(m, float("nan")) for m in TIMELINE}}}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--config", help="a Table 1 config (default: a 2-scene synthetic one)")
    parser.add_argument("--settings", nargs="+", choices=tuple(SETTINGS), default=["jax", "exported"])
    parser.add_argument("--classifiers", nargs="+", choices=tuple(CLASSIFIERS), default=["shipped"],
                        help="the default config's classifiers (one batched program each)")
    parser.add_argument("--cache-from", type=Path, help="a compilation cache folder ($JAXCLS_CACHE_DIR) filled by a "
                        "run of the same config: each setting's starts as a copy of it and of the exported programs "
                        "and host work beside it (no cold runs)")
    parser.add_argument("--out", help="append the section to this Markdown file")
    parser.add_argument("overrides", nargs="*", help="experiments/table1.py overrides (key=value)")
    args = parser.parse_args(argv)
    if args.config and args.classifiers != parser.get_default("classifiers"):
        parser.error("--classifiers sets the default config's classifiers; a --config names its own")
    settings = {s: SETTINGS[s] for s in args.settings}
    runs: dict[str, list[dict]] = {s: [] for s in settings}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        config = args.config
        if config is None:
            config = str(tmp / "table1.yaml")
            classifiers = ", ".join(f"{c}: '{CLASSIFIERS[c]}'" for c in args.classifiers)
            Path(config).write_text(SMALL.format(data=tmp / "data", classifiers="{" + classifiers + "}"))
        cold: dict[str, dict] = {}
        for s in settings:
            if args.cache_from:  # (JAX's cache, and beside it the exported programs and the host work kept)
                shutil.copytree(args.cache_from, tmp / s / "xla")
                for beside in ("exported", "host"):
                    if (args.cache_from.parent / beside).is_dir():
                        shutil.copytree(args.cache_from.parent / beside, tmp / s / beside)
            else:
                cold[s] = _run(s, tmp / s / "xla", config, tmp / f"{s}_cold", args.overrides)
        print("cold", {s: (round(r["wall"], 1), r["first"]) for s, r in cold.items()}, file=sys.stderr)
        for r in range(args.rounds):
            for s in settings if r % 2 == 0 else reversed(settings):
                runs[s].append(_run(s, tmp / s / "xla", config, tmp / f"{s}_{r}", args.overrides))
                print(s, r, {k: round(v, 1) for k, v in runs[s][-1].items() if k not in ("records", "timeline")},
                      file=sys.stderr)
    reference = next(iter(cold.values() or runs[next(iter(settings))]))["records"]
    same = all(run["records"] == reference for rs in [*runs.values(), list(cold.values())] for run in rs)
    rows = []
    for s, name in settings.items():
        rs = runs[s]
        med = {k: statistics.median(run[k] for run in rs) for k in ("wall", "first", "run", "started")}
        spread = f"{min(run['first'] for run in rs):.1f}-{max(run['first'] for run in rs):.1f}"
        cold_first = f"{cold[s]['first']:.1f}" if s in cold else "(copied cache)"
        rows.append((name, report.device_name(), cold_first, f"{med['first']:.1f}", spread,
                     f"{med['started']:.1f}", f"{med['run']:.1f}", f"{med['wall']:.1f}"))
    timeline = [(name, *(f"{statistics.median(run['timeline'][m] for run in runs[s]):.1f}"
                         for m in (STARTUP, *TIMELINE))) for s, name in settings.items()]
    timeline_table = report.table(("cache", "imports and config done", *TIMELINE), timeline)
    report.publish(report.section(
        "Table 1's warm start: " + " against ".join(settings.values()), argv,
        ("cache", "device", "cold first call s", "warm first call s (median)", "range",
         "warm: first call dispatched, s after the process started (median)", "warm run s (median)",
         "warm process wall s (median)"), rows,
        intro=f"{args.rounds} warm runs a setting, alternating, each a fresh process after "
              + (f"its cache folder was copied from {args.cache_from}" if args.cache_from else
                 "one cold run a setting in its own cache folder") + "; config "
              f"{args.config or 'a 2-scene synthetic one, classifiers ' + ', '.join(args.classifiers)}.",
        notes=[f"every run's records are {'the same' if same else 'NOT the same'}"])
        + "\nA warm run's start: when each step was done, s after the process started (median; nan: not in this "
          "run, e.g. frames not made ahead)\n\n" + timeline_table + "\n", args.out)


if __name__ == "__main__":
    main()
