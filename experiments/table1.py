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
runs on the first ``oracle_scenes`` scenes only (it tries every candidate at every move), 64 episodes a call
on an accelerator (``oracle_runs_per_call``). On a GPU, float32 products run at full precision
(``jaxcls.precision``).

Episodes stream to ``out_dir/episodes.jsonl`` as each scene's runs of a row finish; running the command
again skips what is there (an interrupted run resumes without redoing or losing an episode; a torn last
line is dropped). Same config, same numbers. Outputs in ``out_dir``: ``table.md`` (the table laid out as the
paper's, per classifier, then the paired differences and moves-to-correct), ``table.csv`` (every row x
move), ``figure4.png`` (F1 over moves, with 95% bands), ``timing.json`` (each module's time per move).

One host with several GPUs (``--local-processes N``): this process starts N processes, process i on the i-th
visible GPU with ``--processes N --process-id i``; each runs the scenes s with s % N == i (the oracle: its calls
i, i + N, ...) and appends to ``episodes.<i>.jsonl`` (its output in ``process.<i>.log``); this one shows their
progress, stops them all if one fails, and writes the tables. They do not use ``jax.distributed``, so each
shares the compiled programs of a one-GPU run in the compilation cache (``jaxcls.experiments.table1.local`` says
why). Or one process drives every local device (the episodes sharded over them, ``episode.batched``): slower, it
renders every chunk on one GPU.

    python experiments/table1.py --config table1_real_like_scale --local-processes 4

Several hosts (``--distributed``): start the same command once per host (process), each with
``jax.distributed``'s coordinator, the process count and its index (or none of them where JAX detects the
cluster: SLURM, Open MPI, ...); the scenes split and stored as above, whatever the process count (a resumed run
reads every store); once all are done, process 0 writes the tables. (A dataset folder is best rendered before,
by ``jaxcls dataset``, or the scenes drawn with ``scene_source=device``.)

    python experiments/table1.py --config table1_synthetic_scale --distributed \
        --coordinator host0:1234 --processes 2 --process-id 0        # on host 0; --process-id 1 on host 1

This is the command line; the logic is ``jaxcls.experiments.table1`` (``config``, ``data``, ``runner``,
``scoring``, ``tables``, ``figure``).
"""

from __future__ import annotations

import sys
from pathlib import Path

from jaxcls.experiments.table1 import local

# --local-processes: its processes started here, before this one loads JAX and the config's schema, where that is
# safe (local.start_early: ~3 s sooner on a GPU host); main hands them on, or stops them if it refuses the command.
# (The imports below load JAX, so they come after it: pyproject.toml lets this file import below code.)
EARLY = local.start_early(sys.argv[1:], Path(__file__).resolve()) if __name__ == "__main__" else None

import argparse
import json
import os
import time

import jax
from jax.experimental import multihost_utils

from jaxcls import compile_cache, io, precision, report
from jaxcls.config import load_config, save_config
from jaxcls.experiments.table1 import data, runner, tables
from jaxcls.experiments.table1.config import SceneSource, Table1Config, check_out_dir
from jaxcls.world.objects import object_set_from_config

STARTUP = "start-up (Python, imports, config)"
SHUTDOWN_WAIT_SECONDS = 6 * 3600  # how long the other processes of a --distributed run wait for process 0 at exit


def main(argv: list[str] | None = None, command_line: bool = False, early: local.Started | None = None) -> None:
    """The experiment (``argv``: its arguments, default the process's); ``command_line``: this process runs it
    alone (its start-up phase then counts from the process's start: Python and the imports); ``early``:
    ``--local-processes``' processes already started for these arguments (``local.start_early``), stopped if the
    command is refused."""
    try:
        _main(argv, command_line, early)
    finally:
        if early is not None:
            early.stop()  # (nothing left running once the command ends; a no-op after local.run)


def _main(argv: list[str] | None, command_line: bool, early: local.Started | None) -> None:
    main_began = time.perf_counter()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="table1_synthetic", help="a path or a shipped config name")
    parser.add_argument("--out", help="append the tables to this Markdown file")
    parser.add_argument("--tables-only", action="store_true",
                        help="only the tables of the episodes stored in out_dir (none run, no scene file read)")
    parser.add_argument("--record", nargs="+", default=[], metavar="[CLASSIFIER:]ROW:SCENE:RUN",
                        help="also replay these episodes move by move and record each for rerun's 3-D viewer: "
                             "out_dir/recordings/*.rrd (jaxcls view FILE)")
    parser.add_argument("--local-processes", type=int, metavar="N",
                        help="start N processes on this host, one a GPU (the i-th visible one), and make the tables "
                             "when they are done (jaxcls.experiments.table1.local)")
    parser.add_argument("--distributed", action="store_true",
                        help="one process of several (hosts): jax.distributed.initialize, the scenes split by process")
    parser.add_argument("--coordinator", help="with --distributed: host:port of process 0 (else detected)")
    parser.add_argument("--processes", type=int,
                        help="with --distributed: the process count (else detected); without it: one of "
                             "--local-processes' processes (episodes only, no tables)")
    parser.add_argument("--process-id", type=int, help="this process's index (with --distributed: else detected)")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_intermixed_args(argv)
    # One of --local-processes' processes: its share of the scenes, no jax.distributed, no tables.
    local_share = None
    if args.local_processes is not None:
        if args.local_processes < 1:
            parser.error(f"--local-processes must be at least 1, got {args.local_processes}")
        if (args.distributed or args.coordinator or args.processes is not None or args.process_id is not None
                or args.tables_only or args.record):
            parser.error("--local-processes starts its own processes: leave out --distributed, --coordinator, "
                         "--processes, --process-id, --tables-only and --record (record afterwards with "
                         "--tables-only --record ...)")
    elif args.distributed:
        jax.config.update("jax_cpu_collectives_implementation", "gloo")  # (the barrier, where processes are CPUs)
        # The other processes wait at shutdown while process 0 makes the tables (JAX's default wait is 5 min).
        jax.distributed.initialize(args.coordinator, args.processes, args.process_id,
                                   shutdown_timeout_seconds=SHUTDOWN_WAIT_SECONDS)
    elif args.coordinator:
        parser.error("--coordinator needs --distributed")
    elif args.processes is not None or args.process_id is not None:
        if args.processes is None or args.process_id is None or not 0 <= args.process_id < args.processes:
            parser.error("a local process needs --processes N and --process-id I with 0 <= I < N "
                         f"(got {args.processes} and {args.process_id})")
        if args.tables_only or args.record:
            parser.error("--processes / --process-id without --distributed run episodes only: leave out "
                         "--tables-only and --record")
        local_share = (args.process_id, args.processes)
    if args.local_processes is not None:
        jax.config.update("jax_platforms", "cpu")  # (its processes hold the GPUs; this one reads and tabulates)
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
    rows_early = None  # --local-processes: rows tabulated while the processes still run (tables.EarlyRows)
    classes = None  # the object set's class count, where known already
    if args.tables_only:
        dataset = data.dataset_config(config)
        records = data.stored_records(config, store)
        if not records:  # (rather than tables of nothing over the ones there)
            parser.error(f"--tables-only: no episodes of this config's rows and classifiers in {out} "
                         f"({store.name} and its process stores, or their .xz archives)")
    elif args.local_processes is not None:
        dataset, scene_set = data.open_scenes(config)  # (a dataset's missing scenes rendered here, once)
        save_config(config, out / "config.yaml")
        every = runner.episode_keys(config, scene_set.count)
        stored = {data.record_key(r) for r in data.read_stores(store)} & set(every)
        # The batched rows' tables made while the processes run the oracle (each runs it after its batched rows).
        classes = len(object_set_from_config(dataset.objects).classes)
        rows_early = tables.EarlyRows(config, classes, every, select=lambda so_far: data.of_config(config, so_far))
        lines = local.commands(Path(__file__).resolve(), ["--config", args.config, *args.overrides],
                               args.local_processes)
        if early is not None and (early.command_lines != lines or early.out.resolve() != out.resolve()):
            early.stop()  # (started for other arguments: not these)
            early = None
        with clock(f"episodes ({args.local_processes} processes)"):
            processes = early or local.start(lines, local.visible_gpus(args.local_processes), out)
            records = local.run(processes, lambda: data.store_paths(store), len(every), len(stored),
                                offer=rows_early.offer)
        records = data.of_config(config, records)
        clock.episodes = len(records) - len(stored)
        timing = json.loads(timing_file.read_text()) if timing_file.exists() else None  # (process 0's)
    else:
        share = local_share or runner.process_share()
        if args.distributed and config.scene_source is SceneSource.dataset:  # missing scenes rendered once
            if share[0] == 0:
                data.open_scenes(config)
            multihost_utils.sync_global_devices("table1: the dataset is rendered")
        with clock("start-up (devices, renderer)"):  # (the accelerator's runtime and the renderer start here)
            dataset, scene_set = data.open_scenes(config)
            jax.devices()
        clock.mark(runner.DEVICES_READY)
        if share[0] == 0:
            save_config(config, out / "config.yaml")
        if args.distributed and share[0] == 0:  # (it makes the tables)
            others = data.follow_other_stores(store, share)
        records = runner.run_episodes(config, scene_set, dataset, store, show_progress=local_share is None,
                                      process=share, clock=clock)
        if local_share is not None:  # (--local-processes' process: the tables are the launcher's)
            if share[0] == 0 and timing is None and config.timing_moves:
                io.write_json(timing_file, runner.time_modules(config, scene_set, dataset))
            finish_run_times(clock, store, started, share)
            return
    if args.distributed:  # every process's episodes stored; process 0 writes the tables
        with clock("waiting for the other processes"):
            multihost_utils.sync_global_devices("table1: every process's episodes stored")
        if runner.process_share()[0]:
            finish_run_times(clock, store, started, runner.process_share())
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
        classes = classes or len(object_set_from_config(dataset.objects).classes)
        markdown, csv_rows, curves = tables.tables(config, records, classes, timing, argv,
                                                   rows_early.result() if rows_early is not None else None)
        io.write_text(out / "table.md", markdown)
        io.write_text(out / "table.csv", tables.csv_text(csv_rows))
        if curves:
            from jaxcls.experiments.table1 import figure  # (here: matplotlib's import, ~0.3 s, off the start-up)

            figure.figure4(curves, out / "figure4.png")
    finish_run_times(clock, store, started, runner.process_share() if args.local_processes is None else (0, 1),
                     args.local_processes)
    print(f"{len(records)} episodes in {out} ({time.perf_counter() - started:.0f} s this run)", file=sys.stderr)
    report.publish(markdown, args.out)
    if args.distributed:
        jax.distributed.shutdown()


def finish_run_times(clock: runner.Phases, store: Path, started: float, share: tuple[int, int],
                     local_processes: int | None = None) -> None:
    """This process's phases, from its start (Python, imports) to now, appended to its ``run_times.json``
    (``runner.run_times_file``: ``run_times.<i>.json`` for process i of several) where it ran episodes, or
    (``local_processes``) its processes did (theirs: ``run_times.<i>.json``)."""
    if clock.episodes:
        runner.write_run_times(runner.run_times_file(store, share), clock,
                               clock.seconds.get(STARTUP, 0.0) + time.perf_counter() - started,
                               device=local_processes and f"{local_processes} processes (run_times.<i>.json)")


if __name__ == "__main__":
    main(command_line=True, early=EARLY)
    # Done, every file written: end without tearing down the accelerator's runtime and the episodes' memory
    # (~6 s on an H200 after a 1,000-scene run, in every process of a run split over GPUs).
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)
