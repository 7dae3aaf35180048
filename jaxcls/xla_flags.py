"""Keep a long process under the kernel's memory-map limit: XLA:CPU settings that give a compiled program
fewer memory maps, and a guard that frees compiled programs before the limit is reached.

Why. Linux caps the memory maps of a process (``vm.max_map_count``, 65,530 by default; one line each of
``/proc/self/maps``); past it, ``mmap`` fails and XLA dies inside LLVM while compiling ("Fatal Python
error: Segmentation fault" in ``backend_compile_and_load``). XLA:CPU JIT-compiles a program with LLVM's
ORC JIT and loads each object file into a mapping of its own, which ``mprotect`` splits into three maps
(code r-x, read-only data r--, data rw-: XLA's ``ContiguousSectionMemoryManager``). With XLA's defaults
every fusion is emitted (by the "fusion emitters") as an LLVM module of its own, hence an object file and
three maps per fusion: the episode's jitted ``step`` (~1,200 kernels) held 3,530 maps, a 2-move
``jaxcls run`` ~5,600, and a dozen distinct sets of programs in one process reached the limit.

What.

1. ``FLAGS``: ``--xla_cpu_use_fusion_emitters=false`` emits the fusions into the one LLVM module that
   also holds XLA's other host kernels, which XLA splits into ``--xla_cpu_parallel_codegen_split_count``
   parts (32 by default, three maps each) compiled in parallel; ``SPLIT_COUNT`` (4) parts still keep four
   cores compiling one program (on 2 cores, 2 and 4 parts compile as fast as 32). The kernels XLA always
   compiles as modules of their own (unfused reductions and reduce-windows, small dots, small called
   computations, ...) keep three maps each. Measured (``benchmarks/memory_maps.py``, 2-core CPU, medians
   of 2 rounds, XLA's defaults -> these flags): the episode's ``step_jit`` 3,529 -> 1,026 maps, compiled
   in 22.0 -> 12.7 s, a move 80 -> 75 ms; its stage programs (``timed_step``, ``jaxcls run``'s path)
   3,541 -> 1,084 maps, 23.6 -> 12.7 s, a move 90 -> 67 ms; small distinct programs 86 -> 62 maps each.
   Labels and views are the same; float results differ by rounding (a fused loop compiled by another code
   generator), which thresholds and ICP's near-ties can carry further (after 5 moves: a refined pose by up
   to ~0.1, a voxel's TSDF weight by one observation). ``apply`` appends the flags to
   ``$XLA_FLAGS`` (a flag already there is kept as set) when ``jaxcls`` is imported. XLA reads
   ``$XLA_FLAGS`` once, when JAX starts its CPU backend: a process that ran a JAX computation before it
   imported ``jaxcls`` keeps XLA's defaults (a warning says so) and its subprocesses get the flags.
   ``JAXCLS_XLA_FLAGS=off`` leaves ``$XLA_FLAGS`` alone, and so does a jaxlib other than those
   ``CHECKED_JAXLIB`` names (XLA aborts on a flag it does not know).
2. The guard (``install_guard``): before every XLA compilation (JAX's backend-compile event, which loads
   from the persistent compilation cache pass too), once the process holds more than ``GUARD_SHARE`` of
   ``vm.max_map_count``, every compiled program JAX keeps is freed (``jax.clear_caches()``): a program
   that is needed again compiles again (or loads from the persistent cache). However many distinct
   programs a process compiles, its map count stays bounded. ``apply`` installs it as soon as JAX is
   imported (at once if it already is), without importing JAX itself (``jaxcls --help`` starts fast).
   Programs that something else still holds (a ``jax.stages.Compiled``) are not freed.

JAX's persistent compilation cache keys its entries by ``$XLA_FLAGS`` too: entries written with other flags
are not loaded (the first run after the change compiles afresh).
"""

from __future__ import annotations

import gc
import importlib.abc
import importlib.metadata
import importlib.util
import logging
import os
import sys
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path

ENV = "JAXCLS_XLA_FLAGS"
OFF = ("off", "none", "0", "false")
# XLA aborts the process on a flag in $XLA_FLAGS that it does not know, and it drops flags as features settle:
# the flags are set only with the jaxlib versions they were checked with (measure again, then add a version).
CHECKED_JAXLIB = ("0.10.",)
SPLIT_COUNT = 4
FLAGS = {
    "xla_cpu_use_fusion_emitters": "false",
    "xla_cpu_parallel_codegen_split_count": str(SPLIT_COUNT),
}
# Share of vm.max_map_count above which the guard frees every compiled program before the next compilation.
GUARD_SHARE = 0.75
_BACKEND_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"  # jax._src.dispatch.BACKEND_COMPILE_EVENT

log = logging.getLogger(__name__)


def map_limit() -> int:
    """``vm.max_map_count`` (0 where there is none to read: not Linux)."""
    try:
        return int(Path("/proc/sys/vm/max_map_count").read_text())
    except (OSError, ValueError):
        return 0


def count_maps() -> int:
    """The memory maps this process holds now (lines of ``/proc/self/maps``; 0 where there is none)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


def _flag_names(value: str) -> set[str]:
    return {word.lstrip("-").split("=", 1)[0] for word in value.split() if word.startswith("--")}


def with_flags(xla_flags: str | None) -> str:
    """``xla_flags`` (a ``$XLA_FLAGS`` value) with each of ``FLAGS`` appended unless it already names it."""
    current = (xla_flags or "").strip()
    present = _flag_names(current)
    extra = [f"--{name}={value}" for name, value in FLAGS.items() if name not in present]
    return " ".join([current, *extra]).strip()


def jaxlib_checked() -> bool:
    """Whether the installed jaxlib is one ``FLAGS`` were checked with (``CHECKED_JAXLIB``)."""
    try:
        return importlib.metadata.version("jaxlib").startswith(CHECKED_JAXLIB)
    except importlib.metadata.PackageNotFoundError:
        return False


def _backend_started() -> bool:
    bridge = sys.modules.get("jax._src.xla_bridge")
    return bool(getattr(bridge, "_backends", None))


@dataclass
class GuardStats:
    """What the guard saw: the most maps at the start of a compilation, how often it freed programs, and the
    maps left after the last time (what JAX's programs do not hold)."""

    peak: int = 0
    frees: int = 0
    limit: int = 0
    left: int = 0


stats = GuardStats()
_guard_lock = threading.Lock()
_installed = False


def _before_compile(event: str, value: float, **kwargs) -> None:
    if event != _BACKEND_COMPILE_EVENT or not stats.limit:
        return
    maps = count_maps()
    stats.peak = max(stats.peak, maps)
    threshold = GUARD_SHARE * stats.limit
    if stats.left > threshold:  # freeing JAX's programs left the count above the budget (something else holds
        threshold = stats.left + stats.limit // 20  # the maps): not again at every compilation, only once it grew
    if maps <= threshold or not _guard_lock.acquire(blocking=False):
        return
    try:
        import jax

        jax.clear_caches()
        gc.collect()
        stats.frees += 1
        stats.left = count_maps()
        log.info("jaxcls: %d of %d memory maps held; JAX's compiled programs freed (%d left)", maps, stats.limit,
                 stats.left)
        if stats.left > GUARD_SHARE * stats.limit:
            warnings.warn(f"jaxcls: {stats.left} of {stats.limit} memory maps (vm.max_map_count) still held "
                          "after freeing JAX's compiled programs: something else holds them", RuntimeWarning,
                          stacklevel=2)
    finally:
        _guard_lock.release()


def install_guard() -> bool:
    """Free JAX's compiled programs before a compilation once the process holds more than ``GUARD_SHARE`` of
    ``vm.max_map_count`` (once per process; imports JAX). False where there is no limit to read."""
    global _installed
    stats.limit = map_limit()
    if _installed or not stats.limit:
        return _installed
    import jax.monitoring

    jax.monitoring.register_scalar_listener(_before_compile)
    _installed = True
    return True


class _AfterImport(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Runs ``install_guard`` once ``jax`` has been imported (a one-shot post-import hook)."""

    def __init__(self) -> None:
        self._loader: importlib.abc.Loader | None = None

    def find_spec(self, name, path=None, target=None):
        if name != "jax" or self._loader is not None:
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            return spec
        self._loader, spec.loader = spec.loader, self
        return spec

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:
        module.__spec__.loader = module.__loader__ = self._loader
        self._loader.exec_module(module)
        try:
            install_guard()
        except Exception as e:  # the guard is a safety net: never fail JAX's import for it
            warnings.warn(f"jaxcls: memory-map guard not installed: {e}", RuntimeWarning, stacklevel=2)

    def __getattr__(self, name):
        return getattr(self._loader, name)


def apply() -> None:
    """Append ``FLAGS`` to ``$XLA_FLAGS`` and install the guard when JAX is imported (at once if it is).
    Called when ``jaxcls`` is imported; ``JAXCLS_XLA_FLAGS=off``, or a jaxlib the flags were not checked
    with, skips the flags (the guard stays)."""
    if os.environ.get(ENV, "").strip().lower() not in OFF and jaxlib_checked():
        before = os.environ.get("XLA_FLAGS", "")
        after = with_flags(before)
        if after != before.strip():
            if _backend_started():
                warnings.warn("jaxcls: JAX's backend started before jaxcls was imported, so this process "
                              "compiles with XLA's defaults (more memory maps per program; the "
                              "guard still frees programs near the limit); import jaxcls first to get "
                              f"{after[len(before.strip()):].strip()}", RuntimeWarning, stacklevel=3)
            os.environ["XLA_FLAGS"] = after
    if "jax" in sys.modules:
        install_guard()
    elif not any(isinstance(f, _AfterImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterImport())


__all__ = ["CHECKED_JAXLIB", "ENV", "FLAGS", "GUARD_SHARE", "SPLIT_COUNT", "GuardStats", "apply", "count_maps",
           "install_guard", "jaxlib_checked", "map_limit", "stats", "with_flags"]
