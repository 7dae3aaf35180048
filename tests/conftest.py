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

The suite compiles at XLA's lowest optimisation (``jax_disable_most_optimizations``; its subprocesses through
``$JAX_DISABLE_MOST_OPTIMIZATIONS``): most of its time is XLA compiling programs that then run on small inputs, and
LLVM's optimisation was the larger part of that (the whole suite under -n 2 on the 2-core CPU: 16 min 8 s at full
optimisation, 13 min 13 s so, on 2026-11-29).
What a test checks holds at any level: programs compute the same things, rounded otherwise. A test marked
``optimised`` runs at XLA's full optimisation, as outside the tests: one that compares two programs to the last
digits (at the lowest level two programs of the same step round apart, and ICP's near-ties carry it), or whose
running time is larger than its compiling. Between an unmarked and a marked test every compiled program is freed
(``jax.clear_caches``), since the level is not part of JAX's key for a compiled program.
``JAX_DISABLE_MOST_OPTIMIZATIONS=0`` runs the whole suite at full optimisation.
"""

from __future__ import annotations

import collections
import gc
import os

import jax
import pytest

from jaxcls import compile_cache, xla_flags

os.environ.setdefault(compile_cache.ENV, "off")  # subprocesses (the CLI tests) inherit it
_LOWEST = "JAX_DISABLE_MOST_OPTIMIZATIONS"
_SUITE_LOWEST = os.environ.setdefault(_LOWEST, "1").lower() in ("1", "true", "yes")  # the suite's level (unmarked)

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
# The longest tests outside _ONE_WORKER's files, longest first (seconds on the 2-core CPU under -n 2). Under -n,
# loadgroup deals out the groups (largest first), then every other test, one at a time, in the collection's order:
# these go first, and the short ones last, so that neither worker runs a long test alone at the end while the other
# has finished (a 170 s test dealt out last kept one worker busy ~100 s past the other).
_LONGEST = {name: rank for rank, name in enumerate((
    "test_table1.py::test_the_oracle_bounds_a_policy_one_move_ahead",  # ~165 s
    "test_batched.py::test_one_program_runs_every_row_as_its_own_program_does",  # ~110
    "test_readme.py::test_readme_python_examples_run",  # ~65
    "test_table1.py::test_interrupted_experiment_resumes_and_the_same_seed_gives_the_same_numbers",  # ~60
    "test_batched.py::test_episodes_that_render_as_they_move_give_the_records_of_frames_rendered_before",  # ~60
    "test_user_models.py::test_own_models_dataset_train_table1[folders]",  # ~55
    "test_counting.py::test_empty_slots_stay_finite_and_are_ignored",  # ~40
    "test_visibility.py::test_the_continuous_policy_ends_at_least_as_high_as_the_best_candidate",  # ~30
    "test_scene_source.py::test_worker_processes_make_the_same_clouds",  # ~30
    "test_user_models.py::test_own_models_dataset_train_table1[bop]",  # ~25
    "test_scene_source.py::test_scene_clouds_are_pure_labelled_segments_and_resume",  # ~25
    "test_lookalike.py::test_a_tiny_training_run_of_pointnet_hard",  # ~20
    "test_notebooks.py::test_notebook_runs_and_ends_in_a_figure[quickstart.ipynb]",  # ~20
))}
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
def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in _ONE_WORKER:
            item.add_marker(pytest.mark.xdist_group(item.path.stem))
    if hasattr(config, "workerinput"):  # a worker of -n: the longest tests first (_LONGEST)
        items.sort(key=lambda item: _LONGEST.get(f"{item.path.name}::{item.name}", len(_LONGEST)))


_level: dict[str, bool] = {}  # {"lowest": the level programs compile at now}


def _compile_at_lowest(lowest: bool) -> None:
    """Compile at XLA's lowest optimisation (``lowest``) or its full one, here and in subprocesses started from
    now; every compiled program is freed when the level changes."""
    if _level.get("lowest") != lowest:
        jax.config.update("jax_disable_most_optimizations", lowest)
        if _level:
            jax.clear_caches()
        _level["lowest"] = lowest
    os.environ[_LOWEST] = "1" if lowest else "0"


_compile_at_lowest(_SUITE_LOWEST)


@pytest.hookimpl(tryfirst=True)  # (before the test's fixtures are set up: theirs compile at its level too)
def pytest_runtest_setup(item):
    _compile_at_lowest(_SUITE_LOWEST and item.get_closest_marker("optimised") is None)


@pytest.fixture
def host_arrays(monkeypatch) -> dict:
    """The ``cached_arrays`` entries (kind, key) -> arrays this test's own work uses, filled as it asks for them:
    for a subprocess of the test, which otherwise builds them again (~10 s of ICP targets for a model library on
    the 2-core CPU), to hand out as built (the conftest's memory does the same here: a pure function of its key)."""
    used: dict = {}
    inner = compile_cache.cached_arrays

    def recording(kind, key, build):
        used[kind, key] = arrays = inner(kind, key, build)
        return arrays

    monkeypatch.setattr(compile_cache, "cached_arrays", recording)
    return used


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
