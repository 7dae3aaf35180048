"""Shared test set-up: a long test process stays under the kernel's memory-map limit, and says how close it came.

Every program XLA:CPU compiles holds memory maps (three per object file of machine code); a process may hold
``vm.max_map_count`` of them (65,530 by default), and past it XLA dies inside LLVM while compiling (a
segmentation fault). ``jaxcls.xla_flags``, set up when ``jaxcls`` is imported (below, before any test runs
JAX), gives each program fewer maps and frees JAX's compiled programs before a compilation once the process
holds 3/4 of the limit. Here, in addition, after a test that leaves the process above ``_MAP_BUDGET`` of the
limit, JAX's caches are cleared at once: at a test's end rather than in the middle of the next one (whose
checks of what compiles when a guard would upset). Later tests compile again what they need.

At the end of a run in one process, the summary gives the most maps the process held (after a test, and
at the start of a compilation) and how often programs were freed; ``JAXCLS_MAPS_LOG=<file>`` appends the
same line from each process (each worker of ``-n``) to that file.

The suite runs with the persistent compilation cache off (``JAXCLS_CACHE_DIR=off`` unless set): each test
compiles what it checks, and test workers never share cache files; ``tests/test_compile_cache.py`` turns it
on in folders of its own.
"""

from __future__ import annotations

import gc
import os

import jax
import pytest

from jaxcls import compile_cache, xla_flags

os.environ.setdefault(compile_cache.ENV, "off")  # subprocesses (the CLI tests) inherit it

_MAP_BUDGET = 0.5  # share of vm.max_map_count a process may hold after a test before its programs are freed
_LIMIT = xla_flags.map_limit()
_seen = {"after_test": 0, "freed_after_test": 0}


@pytest.fixture(autouse=True)
def _free_compiled_programs_near_the_map_limit():
    yield
    if not _LIMIT:
        return
    maps = xla_flags.count_maps()
    _seen["after_test"] = max(_seen["after_test"], maps)
    if maps > _MAP_BUDGET * _LIMIT:
        jax.clear_caches()
        gc.collect()
        _seen["freed_after_test"] += 1


def _summary() -> str:
    s = xla_flags.stats
    return (f"memory maps: at most {max(_seen['after_test'], s.peak)} of {_LIMIT} (vm.max_map_count) in process "
            f"{os.getpid()}: {_seen['after_test']} after a test, {s.peak} at a compilation's start; programs freed "
            f"{_seen['freed_after_test']} times after a test, {s.frees} times by the guard")


def pytest_sessionfinish(session):
    if _LIMIT and os.environ.get("JAXCLS_MAPS_LOG") and _seen["after_test"]:  # not xdist's controller
        with open(os.environ["JAXCLS_MAPS_LOG"], "a") as f:
            f.write(_summary() + "\n")


def pytest_terminal_summary(terminalreporter):
    if _LIMIT and not os.environ.get("PYTEST_XDIST_WORKER") and _seen["after_test"]:
        terminalreporter.write_line(_summary())
