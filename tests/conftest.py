"""Shared test set-up: keep a long-lived test worker under the kernel's memory-map limit.

Every XLA:CPU executable maps its code in a few thousand memory regions; a pytest worker that keeps every
program it compiled reaches ``vm.max_map_count`` (65,530 by default) after a few hundred episode programs
and dies inside LLVM (a segmentation fault or 'Cannot allocate memory' while compiling, as
``experiments/table1.py`` met on long CPU runs). After a test, once the process holds more than
``_MAP_BUDGET`` of the limit, JAX's caches are cleared and the executables freed: later tests compile
again what they need.

The suite runs with the persistent compilation cache off (``JAXCLS_CACHE_DIR=off`` unless set): each test
compiles what it checks, and test workers never share cache files; ``tests/test_compile_cache.py`` turns it
on in folders of its own.
"""

from __future__ import annotations

import gc
import os
from pathlib import Path

import jax
import pytest

from jaxcls import compile_cache

os.environ.setdefault(compile_cache.ENV, "off")  # subprocesses (the CLI tests) inherit it

_MAP_BUDGET = 0.5  # share of vm.max_map_count a worker may hold before its compiled programs are freed


def _map_limit() -> int:
    try:
        return int(Path("/proc/sys/vm/max_map_count").read_text())
    except (OSError, ValueError):
        return 0


def _maps() -> int:
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


_LIMIT = _map_limit()


@pytest.fixture(autouse=True)
def _free_compiled_programs_near_the_map_limit():
    yield
    if _LIMIT and _maps() > _MAP_BUDGET * _LIMIT:
        jax.clear_caches()
        gc.collect()
