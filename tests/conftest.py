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

Under ``-n`` (pytest-xdist), the tests of each file in ``_ONE_WORKER`` run in one worker (``--dist loadgroup``
in place of the default ``load``, each such file an ``xdist_group``): their module-scoped fixtures (a world, an
episode, a short training run) and the programs their tests compile are built once, not once in each worker
that ``load`` hands some of the file's tests to. Every other test is dealt out as ``load`` deals it.

The suite runs with the persistent compilation cache off (``JAXCLS_CACHE_DIR=off`` unless set): each test
compiles what it checks, and test workers never share cache files; ``tests/test_compile_cache.py`` turns it
on in folders of its own. The host work that the cache keeps on disk beside the programs
(``compile_cache.cached_arrays``: an ICP target's closest-sample lookups, ~0.2 s a model, 32 to 96 models a
model library, built again for every episode and library) is kept in the process's memory instead while the
cache is off: a pure function of its key (every input), built once a process and handed out as built (nothing
writes to it). With the cache on (``_host`` set), ``cached_arrays`` behaves as it does outside the tests.
"""

from __future__ import annotations

import collections
import gc
import os

import jax
import pytest

from jaxcls import compile_cache, xla_flags

os.environ.setdefault(compile_cache.ENV, "off")  # subprocesses (the CLI tests) inherit it

_MAP_BUDGET = 0.5  # share of vm.max_map_count a process may hold after a test before its programs are freed
_HOST_ENTRIES = 160  # cached_arrays entries kept in memory (an ICP target's lookups: ~0.5-2 MB)
_host_arrays: collections.OrderedDict = collections.OrderedDict()
_cached_arrays = compile_cache.cached_arrays


def _cached_arrays_in_memory(kind, key, build):
    """``compile_cache.cached_arrays`` with the cache off: the arrays built once a process for each key."""
    if compile_cache._host is not None:  # the cache on (test_compile_cache.py): its own behaviour
        return _cached_arrays(kind, key, build)
    if (kind, key) not in _host_arrays:
        _host_arrays[kind, key] = build()
        while len(_host_arrays) > _HOST_ENTRIES:
            _host_arrays.popitem(last=False)
    _host_arrays.move_to_end((kind, key))
    return _host_arrays[kind, key]


compile_cache.cached_arrays = _cached_arrays_in_memory
_ONE_WORKER = ("test_episode.py", "test_observe.py", "test_pointnet.py", "test_refine.py", "test_tracking.py",
               "test_train.py")
_LIMIT = xla_flags.map_limit()
_seen = {"after_test": 0, "freed_after_test": 0}


def pytest_configure(config):
    if getattr(config.option, "dist", "no") == "load":  # -n without --dist: keep _ONE_WORKER's files together
        config.option.dist = "loadgroup"
    if getattr(config, "workerinput", {}).get("jaxcls_loadgroup"):  # a worker (it parses -n, not our choice)
        config.option.loadgroup = True  # xdist's worker then names each item by its group, as loadgroup expects


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node):  # (xdist's controller, for each worker it starts)
    node.workerinput["jaxcls_loadgroup"] = node.config.getvalue("dist") == "loadgroup"


@pytest.hookimpl(tryfirst=True)  # (before xdist's worker names each item by its group)
def pytest_collection_modifyitems(items):
    for item in items:
        if item.path.name in _ONE_WORKER:
            item.add_marker(pytest.mark.xdist_group(item.path.stem))


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
