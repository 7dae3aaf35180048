"""The paper's Table 1 and Figure 4: every row's episodes on a dataset's scenes, with confidence intervals.

    python experiments/table1.py --config table1_synthetic [key=value ...] [--out RESULTS.md]
    python experiments/table1.py --config table1_real_like

The scenes are a ``jaxcls dataset`` (``dataset``: a shipped dataset config name, a config path, or a folder
written by ``jaxcls dataset``; a config's folder is rendered first if it is missing or incomplete, and
``dataset_overrides`` change it, e.g. ``[num_scenes=30,out_dir=data/synthetic_30]``); with
``scene_source=device`` the config's scenes are drawn with its seeds and rendered chunk by chunk where the
episodes run (the scene bank on a GPU, MuJoCo's C caster on a CPU), nothing written. The rows are
``protocol.ROWS`` names (``rows``); each runs ``runs`` episodes per scene from seeded random start views
(the same starts and keys for every row: rows are paired), ``moves`` moves each, with every classifier of
``classifiers`` (name: a ``.msgpack`` path or a shipped name, "" = the shipped weights). The oracle row
runs on the first ``oracle_scenes`` scenes only (it tries every candidate at every move), a scene's runs
together on an accelerator (``oracle_runs_per_call``). On a GPU, float32 products run at full precision
(``jaxcls.precision``).

Episodes stream to ``out_dir/episodes.jsonl`` as each scene's runs of a row finish; running the command
again skips what is there (an interrupted run resumes without redoing or losing an episode; a torn last
line is dropped). Same config, same numbers. Outputs in ``out_dir``: ``table.md`` (the table laid out as the
paper's, per classifier, then the paired differences and moves-to-correct), ``table.csv`` (every row x
move), ``figure4.png`` (F1 over moves, with 95% bands), ``timing.json`` (each module's time per move).

Several hosts (``--distributed``): start the same command once per host (process), each with
``jax.distributed``'s coordinator, the process count and its index (or none of them where JAX detects the
cluster: SLURM, Open MPI, ...); process i runs the scenes s with s % count == i on its local devices and
appends to ``episodes.<i>.jsonl`` (no file is shared while written; a resumed run reads every store, under any
process count); once all are done, process 0 writes the tables. (A dataset folder is best rendered before,
by ``jaxcls dataset``, or the scenes drawn with ``scene_source=device``.) Within one host, one process drives every
local device (the episodes are sharded over them, ``episode.batched``); or one process a GPU, process I started
as ``CUDA_VISIBLE_DEVICES=I python experiments/table1.py ... --distributed --coordinator localhost:PORT
--processes N --process-id I`` (the frames, records and start-up split too).

    python experiments/table1.py --config table1_synthetic_scale --distributed \
        --coordinator host0:1234 --processes 2 --process-id 0        # on host 0; --process-id 1 on host 1

This is the command line; the logic is ``jaxcls.experiments.table1`` (``config``, ``data``, ``runner``,
``scoring``, ``tables``, ``figure``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
from jax.experimental import multihost_utils

from jaxcls import compile_cache, io, precision, report
from jaxcls.config import load_config, save_config
from jaxcls.experiments.table1 import data, figure, runner, tables
from jaxcls.experiments.table1.config import SceneSource, Table1Config, check_out_dir
from jaxcls.world.objects import object_set_from_config

STARTUP = "start-up (Python, imports, config)"
SHUTDOWN_WAIT_SECONDS = 6 * 3600  # how long the other processes of a --distributed run wait for process 0 at exit


def main(argv: list[str] | None = None, command_line: bool = False) -> None:
    """The experiment (``argv``: its arguments, default the process's); ``command_line``: this process runs it
    alone (its start-up phase then counts from the process's start: Python and the imports)."""
    main_began = time.perf_counter()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="table1_synthetic", help="a path or a shipped config name")
    parser.add_argument("--out", help="append the tables to this Markdown file")
    parser.add_argument("--tables-only", action="store_true",
                        help="only the tables of the episodes stored in out_dir (none run, no scene file read)")
    parser.add_argument("--record", nargs="+", default=[], metavar="[CLASSIFIER:]ROW:SCENE:RUN",
                        help="also replay these episodes move by move and record each for rerun's 3-D viewer: "
                             "out_dir/recordings/*.rrd (jaxcls view FILE)")
    parser.add_argument("--distributed", action="store_true",
                        help="one process of several (hosts): jax.distributed.initialize, the scenes split by process")
    parser.add_argument("--coordinator", help="with --distributed: host:port of process 0 (else detected)")
    parser.add_argument("--processes", type=int, help="with --distributed: the process count (else detected)")
    parser.add_argument("--process-id", type=int, help="with --distributed: this process's index (else detected)")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_intermixed_args(argv)
    if args.distributed:
        jax.config.update("jax_cpu_collectives_implementation", "gloo")  # (the barrier, where processes are CPUs)
        # The other processes wait at shutdown while process 0 makes the tables (JAX's default wait is 5 min).
        jax.distributed.initialize(args.coordinator, args.processes, args.process_id,
                                   shutdown_timeout_seconds=SHUTDOWN_WAIT_SECONDS)
    elif args.coordinator or args.processes is not None or args.process_id is not None:
        parser.error("--coordinator, --processes and --process-id need --distributed")
    # No allocator.retain_freed_memory() here: batched episodes gain little from it.
    precision.full_float32_matmuls()  # no TF32 on a GPU (jaxcls.precision)
    compile_cache.enable()  # the row programs kept on disk for the next run (jaxcls.compile_cache)
    config = load_config(Table1Config, args.config, args.overrides)
    runner.chosen_episodes(config, args.record)  # (a bad --record refused before anything runs)
    out = Path(config.out_dir)
    check_out_dir(config, out)
    started, store = time.perf_counter(), out / "episodes.jsonl"
    clock = runner.Phases()  # this run's phases, written to run_times.json where it ran episodes
    # From the process's start where this is the command line (Python and the imports too), else from here.
    clock.seconds[STARTUP] = (command_line and report.process_age()) or started - main_began
    timing_file = out / "timing.json"
    timing = json.loads(timing_file.read_text()) if timing_file.exists() else None
    others = None  # process 0 of several: the other processes' episodes, read while they run
    if args.tables_only:
        dataset = data.dataset_config(config)
        records = data.stored_records(config, store)
    else:
        if args.distributed and config.scene_source is SceneSource.dataset:  # missing scenes rendered once
            if runner.process_share()[0] == 0:
                data.open_scenes(config)
            multihost_utils.sync_global_devices("table1: the dataset is rendered")
        with clock("start-up (devices, renderer)"):  # (the accelerator's runtime and the renderer start here)
            dataset, scene_set = data.open_scenes(config)
            runner.process_share()
        if runner.process_share()[0] == 0:
            save_config(config, out / "config.yaml")
        if args.distributed and runner.process_share()[0] == 0:  # (it makes the tables)
            others = data.follow_other_stores(store, runner.process_share())
        records = runner.run_episodes(config, scene_set, dataset, store, clock=clock)
    if args.distributed:  # every process's episodes stored; process 0 writes the tables
        with clock("waiting for the other processes"):
            multihost_utils.sync_global_devices("table1: every process's episodes stored")
        if runner.process_share()[0]:
            finish_run_times(clock, store, started)
            jax.distributed.shutdown()  # (waits for process 0's tables, SHUTDOWN_WAIT_SECONDS at most)
            return
        with clock("tables and figure"):
            records = (data.stored_records(config, store) if others is None
                       else data.of_config(config, records + others.finish()))
    if args.record:
        if args.tables_only:
            dataset, scene_set = data.open_scenes(config)
        for path in runner.record_episodes(config, scene_set, dataset, args.record, out / "recordings"):
            print(f"recorded {path} (jaxcls view {path})", file=sys.stderr)
    if timing is None and config.timing_moves and not args.tables_only:
        timing = runner.time_modules(config, scene_set, dataset)
        io.write_json(timing_file, timing)
    with clock("tables and figure"):
        classes = len(object_set_from_config(dataset.objects).classes)
        markdown, csv_rows, curves = tables.tables(config, records, classes, timing, argv)
        io.write_text(out / "table.md", markdown)
        io.write_text(out / "table.csv", tables.csv_text(csv_rows))
        if curves:
            figure.figure4(curves, out / "figure4.png")
    finish_run_times(clock, store, started)
    print(f"{len(records)} episodes in {out} ({time.perf_counter() - started:.0f} s this run)", file=sys.stderr)
    report.publish(markdown, args.out)
    if args.distributed:
        jax.distributed.shutdown()


def finish_run_times(clock: runner.Phases, store: Path, started: float) -> None:
    """This process's phases, from its start (Python, imports) to now, appended to its ``run_times.json``
    (``runner.run_times_file``) where it ran episodes."""
    if clock.episodes:
        runner.write_run_times(runner.run_times_file(store, runner.process_share()), clock,
                               clock.seconds.get(STARTUP, 0.0) + time.perf_counter() - started)


if __name__ == "__main__":
    main(command_line=True)
