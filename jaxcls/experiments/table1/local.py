"""Several processes of one host, one a GPU, without ``jax.distributed`` (``experiments/table1.py
--local-processes N``): this process starts N copies of the command, process i with ``CUDA_VISIBLE_DEVICES`` set
to the i-th visible GPU and ``--processes N --process-id i``; each runs the scenes s with s % N == i (the oracle:
its calls i, i + N, ..., ``runner.oracle_calls``) and appends to its own store (``data.process_store``); this one
shows their progress from the stores, stops them all if one fails (naming it and its log), and makes the tables
once they are done.

Why not ``jax.distributed`` on one host: a GPU program's entry in JAX's persistent compilation cache is keyed by
the devices' topology, which under ``jax.distributed`` is the process group's, not the one GPU a process uses;
so a process of a group misses the programs a one-process run compiled, and only process 0 of a group writes
entries (on a CPU every process but 0 compiles on every run). Processes that do not know of each other have a
one-GPU client each: they share every cached program with a one-GPU run of the same shapes. Several hosts still
need ``--distributed``.

Nothing here imports JAX: the command line starts the processes before it loads JAX and the config's schema
where that is safe (``start_early``), ~3 s sooner on a GPU host."""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO

from tqdm.auto import tqdm

from jaxcls import io

# How much of a failed process's log the error shows.
LOG_TAIL_LINES = 30


def visible_gpus(count: int, environ: dict[str, str] | None = None) -> list[str]:
    """The GPU each of ``count`` processes gets (``CUDA_VISIBLE_DEVICES`` values): the i-th of the visible ones
    where ``CUDA_VISIBLE_DEVICES`` lists them (ValueError if it lists fewer than ``count``), else ``"i"``."""
    environ = os.environ if environ is None else environ
    listed = [g.strip() for g in environ.get("CUDA_VISIBLE_DEVICES", "").split(",") if g.strip()]
    if "CUDA_VISIBLE_DEVICES" in environ and len(listed) < count:
        raise ValueError(f"--local-processes {count}: CUDA_VISIBLE_DEVICES lists {len(listed)} GPU(s) "
                         f"({environ['CUDA_VISIBLE_DEVICES']!r}); start at most that many processes")
    return listed[:count] if listed else [str(i) for i in range(count)]


def commands(script: Path, argv: Sequence[str], count: int) -> list[list[str]]:
    """The command line of each of ``count`` processes: ``script`` with ``argv`` (the config and its overrides)
    and ``--processes count --process-id i``."""
    return [[sys.executable, str(script), *argv, "--processes", str(count), "--process-id", str(i)]
            for i in range(count)]


def log_path(out: Path, index: int) -> Path:
    """Where process ``index`` writes its output: ``out_dir/process.<index>.log``."""
    return out / f"process.{index}.log"


@dataclasses.dataclass
class Started:
    """Processes ``start`` started: their command lines, the processes, their open log files."""

    command_lines: list[list[str]]
    processes: list[subprocess.Popen]
    logs: list[IO]
    out: Path

    def stop(self) -> None:
        """Stop the processes still running (terminate, then kill after 30 s) and close their logs."""
        for p in self.processes:
            if p.poll() is None:
                p.terminate()
        for p in self.processes:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
        for f in self.logs:
            f.close()


def start(command_lines: list[list[str]], gpus: list[str], out: Path) -> Started:
    """Start every command: process i on GPU ``gpus[i]``, its output appended to ``log_path(out, i)`` (a resumed
    run's after the earlier runs'; ``out`` made)."""
    out.mkdir(parents=True, exist_ok=True)
    started = Started(command_lines, [], [], out)
    try:
        for i, (line, gpu) in enumerate(zip(command_lines, gpus, strict=True)):
            started.logs.append(open(log_path(out, i), "a"))  # (closed by stop, once it ended)
            started.processes.append(subprocess.Popen(line, stdout=started.logs[-1], stderr=subprocess.STDOUT,
                                                      env={**os.environ, "CUDA_VISIBLE_DEVICES": gpu}))
    except BaseException:
        started.stop()
        raise
    return started


def start_early(argv: Sequence[str], script: Path) -> Started | None:
    """``--local-processes``' processes started from the command line ``argv`` of ``script`` before it imports JAX
    and checks its config, where that is safe: ``argv`` holds only ``--config``, ``--out``, ``--local-processes N``
    (N >= 1) and overrides, and the config (its file and the overrides, read as plain YAML) names its ``out_dir``
    and draws its scenes on the device (``scene_source: device``: no dataset to render first). Else None (the
    command line starts them after its checks, which also refuse what is wrong here). The command line hands the
    result to ``run`` if its own command lines are these (else it stops them and starts its own)."""
    parser = argparse.ArgumentParser(add_help=False, exit_on_error=False)
    parser.add_argument("--config")
    parser.add_argument("--out")
    parser.add_argument("--local-processes", type=int)
    parser.add_argument("overrides", nargs="*")
    try:
        args, rest = parser.parse_known_intermixed_args(argv)
        if rest or args.config is None or args.local_processes is None or args.local_processes < 1:
            return None
        from omegaconf import OmegaConf

        from jaxcls.config import resolve_config

        raw = OmegaConf.merge(OmegaConf.load(resolve_config(args.config)), OmegaConf.from_dotlist(args.overrides))
        out_dir, source = raw.get("out_dir"), raw.get("scene_source")
        gpus = visible_gpus(args.local_processes)
    except Exception:  # (the command line's own checks say what is wrong)
        return None
    if not out_dir or source != "device":
        return None
    return start(commands(script, ["--config", args.config, *args.overrides], args.local_processes), gpus,
                 Path(out_dir))


def run(started: Started, store_paths, total: int, done: int, show_progress: bool = True, poll_seconds: float = 0.1,
        offer: Callable[[list[dict]], None] | None = None, read_seconds: float = 0.5) -> list[dict]:
    """Show the episodes stored by the processes ``started`` (``store_paths()``: the stores; ``total`` episodes
    wanted, ``done`` of them stored before) and wait for them. Returns every stored record (read while they ran:
    ``io.JsonlFollower``); ``offer``: given the records stored so far at every poll while they run
    (``tables.EarlyRows.offer``). The processes are looked at every ``poll_seconds`` (their end noticed that
    soon), the stores read every ``read_seconds``. RuntimeError naming the process, its exit status and the end
    of its log if one fails (the others are stopped); an interrupt stops them all."""
    follower = io.JsonlFollower(store_paths, interval=read_seconds)
    processes, out, records, offered = started.processes, started.out, None, -1
    try:
        # The tables' bootstrap needs SciPy's stats (1-3 s to import): imported while the processes run, not after.
        import scipy.stats  # noqa: F401
        with tqdm(total=total, initial=done, desc=f"episodes ({len(processes)} processes)", unit="episode",
                  disable=not show_progress) as bar:
            while True:
                codes = [p.poll() for p in processes]
                failed = [i for i, c in enumerate(codes) if c not in (None, 0)]
                if failed:
                    i = failed[0]
                    tail = "".join(log_path(out, i).read_text(errors="replace").replace("\r", "\n")
                                   .splitlines(keepends=True)[-LOG_TAIL_LINES:])
                    raise RuntimeError(f"process {i} of {len(processes)} failed (exit status {codes[i]}); the others "
                                       f"were stopped. The end of its log, {log_path(out, i)}:\n{tail}")
                count = follower.count()
                bar.update(max(0, min(total, count) - bar.n))
                if offer is not None and count != offered:  # (only when more were read)
                    offer(follower.records())
                    offered = count
                if all(c == 0 for c in codes):
                    break
                time.sleep(poll_seconds)
            records = follower.finish()
            bar.update(max(0, min(total, len(records)) - bar.n))
        return records
    finally:
        if records is None:
            try:
                follower.finish()  # (stops its thread)
            except ValueError:
                pass  # (a damaged store: the error being raised says more)
        started.stop()
