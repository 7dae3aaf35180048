"""Independent pieces of host work (a dataset's scenes, a training set's clouds) in worker processes.

``run`` calls a function on each of a list of arguments, in this process (``workers`` 1) or in a pool of spawned
processes (not forked: JAX is threaded), each result handed to a callback as it comes (a progress bar, the file it
wrote). Workers keep JAX on the CPU (a GPU host's workers would each claim most of the GPU's memory), start deaf
to Ctrl-C (the terminal's interrupt reaches every process of the job; this one stops them) and, on Linux, end
with the process that started them. A worker's error or an interrupt stops the others at once.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

import jax


def pooled(workers: int, calls: int) -> bool:
    """Whether ``run`` makes ``calls`` calls in worker processes (more than one worker and more than one call)
    rather than here: a caller that hands workers other arguments than its own (names, not objects) asks."""
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    return workers > 1 and calls > 1


def run(function: Callable[..., Any], calls: Sequence[tuple], workers: int,
        done: Callable[[Any], None] = lambda result: None) -> None:
    """``function(*args)`` for each ``args`` of ``calls``, ``done(result)`` after each (in the order they end).
    ``workers`` 1 (or a single call): here, one after another; more: that many spawned processes (``function``
    and its arguments picklable: a module-level function)."""
    if not pooled(workers, len(calls)):
        for args in calls:
            done(function(*args))
        return
    pool = ProcessPoolExecutor(min(workers, len(calls)), mp_context=multiprocessing.get_context("spawn"),
                               initializer=cpu_worker)
    try:
        with sigint_ignored():  # the workers start deaf to Ctrl-C: this process stops them (below)
            futures = [pool.submit(function, *args) for args in calls]
        for future in as_completed(futures):
            done(future.result())
    except BaseException:  # Ctrl-C or a worker's error: the other workers stop now, not after their work
        for process in list((getattr(pool, "_processes", None) or {}).values()):
            process.terminate()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


@contextlib.contextmanager
def sigint_ignored() -> Iterator[None]:
    """SIGINT ignored while worker processes are started, so that they inherit it ignored (a terminal's
    Ctrl-C reaches every process of the job, and a worker stopped halfway through its imports prints a
    traceback); off the main thread, nothing changes."""
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def cpu_worker() -> None:
    """A worker's start: JAX on the CPU, Ctrl-C left to the process that started it and, on Linux, the end of
    that process ending this one (a parent that ends at once on Ctrl-C must not leave workers running on)."""
    jax.config.update("jax_platforms", "cpu")
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    libc = ctypes.util.find_library("c")
    if sys.platform.startswith("linux") and libc:
        ctypes.CDLL(libc).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG: SIGTERM when the parent ends
        if os.getppid() == 1:  # the parent ended before that took effect
            os._exit(1)


__all__ = ["cpu_worker", "pooled", "run", "sigint_ignored"]
