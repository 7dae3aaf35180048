"""JAX's persistent compilation cache for jaxcls's commands and experiments.

A short run spends most of its time compiling (a 10-move ``jaxcls demo``: ~34 s of ~50 s on a 2-core CPU).
With the cache on, every compiled XLA program is also written to a folder, and a later process that
compiles the same program (same code, shapes, settings, JAX version and device) loads it instead.

The folder: ``$JAXCLS_CACHE_DIR`` if set (``off`` turns the cache off), else ``$XDG_CACHE_HOME/jaxcls/xla``
(``~/.cache/jaxcls/xla``). Delete it to start cold; JAX keys entries by everything that changes a program,
so a stale entry is never used for another one. The ``jaxcls`` commands and ``experiments/table1.py`` call
``enable`` at start-up; a notebook or script of your own calls it once, before its first jit.

Host-side work that is as deterministic as a compiled program is kept beside it once ``enable`` ran
(``cached_arrays``: e.g. the ICP targets' closest-sample grids, ``perception.icp.model_target``, ~5 s of a
warm ``jaxcls demo`` on a 2-core CPU), in ``<folder>/../host/<kind>``, keyed by a hash of every input.

JAX's cache keys a program by its lowered form, so a later process still traces and lowers it before the
lookup: for Table 1's episode program most of a warm first call (~5 of 6.6 s on the 2-core CPU). ``exported``
keeps a program's lowered form itself (StableHLO, ``jax.export``) in ``<folder>/../exported/<kind>``, keyed by
what tracing reads, and a later process compiles that (from JAX's cache) without tracing.

Loading even that takes seconds on a GPU (~1.6 s for Table 1's program on an H200: the executable read, its
kernels' annotations built and put on the device; ~3 s with JAX's whole tracebacks in the locations, hence
``one_frame_locations``), while the host would otherwise render frames or wait for the devices: ``ahead`` runs such
a load on a background thread, and ``exported`` takes the arguments' shapes alone (``jax.ShapeDtypeStruct`` with their
sharding) for the arrays that do not exist yet, e.g. frames still to be rendered.
"""

from __future__ import annotations

import functools
import hashlib
import os
import pickle
import threading
import warnings
import zipfile
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

ENV = "JAXCLS_CACHE_DIR"
OFF = ("off", "none", "0", "false", "")
# Programs that compile faster than this are not written. 0: every one is, the smallest too. A warm Table 1
# process then loads the ~60 small programs of its start-up (conversions, concatenations, the sensor's) instead of
# compiling them again (~10 ms each on a 2-core CPU): the first call dispatched 5.3 -> 5.0 s after the process
# started on the 2-core CPU, medians of 5 (BENCHMARKS.md, "Table 1's warm start").
MIN_COMPILE_SECONDS = 0.0
_host: Path | None = None  # where ``cached_arrays`` keeps its entries (set by ``enable``)
_exported: dict[tuple, Callable] = {}  # ``exported``'s programs in this process, by key and compiler options
_making: dict[tuple, threading.Lock] = {}  # one lock a program being made: a second thread waits for the first
_making_lock = threading.Lock()
_background: ThreadPoolExecutor | None = None  # ``ahead``'s threads, started on its first use
# ``ahead``'s loads at once: a program's compilation (or its executable read from JAX's cache) runs outside
# Python's lock, its tracing and deserialising do not; Table 1 loads one program a classifier (BENCHMARKS.md,
# "Programs loaded in parallel").
AHEAD_THREADS = 4
# JAX settings that say where and whether programs are cached, not what they compute: not in ``exported``'s key.
_NOT_IN_KEY = ("compilation_cache", "persistent_cache", "log_compiles", "explain_cache_misses")
# JAX's own setting (read when JAX is imported): set, whole tracebacks stay in the locations (``one_frame_locations``).
FULL_TRACEBACKS_ENV = "JAX_INCLUDE_FULL_TRACEBACKS_IN_LOCATIONS"


def cache_folder() -> Path | None:
    """The folder ``enable`` uses by default (None: ``$JAXCLS_CACHE_DIR`` says off)."""
    value = os.environ.get(ENV)
    if value is not None:
        return None if value.strip().lower() in OFF else Path(value).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jaxcls" / "xla"


def one_frame_locations() -> None:
    """Lower every later program with one Python source frame per operation in its locations (the line that made
    it), not JAX's whole traceback (up to 100 frames): unless ``$JAX_INCLUDE_FULL_TRACEBACKS_IN_LOCATIONS`` says
    otherwise. A GPU builds each kernel's profiler annotation from those frames whenever it compiles or loads a
    program; with whole tracebacks that was half of loading Table 1's episode program from the cache (~3.0 ->
    ~1.6 s a program on an H200, the same records: BENCHMARKS.md, "Table 1's warm start with one source frame
    per operation"). Profiles and XLA's messages still name each operation's function path and its line."""
    import jax

    if FULL_TRACEBACKS_ENV not in os.environ:
        jax.config.update("jax_include_full_tracebacks_in_locations", False)


def enable(folder: str | Path | None = None, min_compile_seconds: float = MIN_COMPILE_SECONDS) -> Path | None:
    """Turn JAX's persistent compilation cache on in ``folder`` (default ``cache_folder()``), and lower programs
    with one source frame per operation (``one_frame_locations``: faster loads, with the cache on or off).
    Returns the folder, or None when the cache is off (``$JAXCLS_CACHE_DIR=off``) or the folder cannot be
    written (a warning says why; the run goes on, compiling as usual)."""
    one_frame_locations()
    target = cache_folder() if folder is None else Path(folder).expanduser()
    if target is None:
        return None
    try:
        target.mkdir(parents=True, exist_ok=True)
        if not os.access(target, os.W_OK):
            raise PermissionError(f"{target} is not writable")
    except OSError as e:
        warnings.warn(f"compilation cache off: {e} (set {ENV} to a writable folder, or {ENV}=off)", stacklevel=2)
        return None
    import jax  # here, not at the top: ``jaxcls --help`` imports this module and should not load JAX

    jax.config.update("jax_compilation_cache_dir", str(target))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_seconds))
    global _host
    _host = target.parent / "host"
    return target


def enabled() -> bool:
    """Whether ``enable`` turned the cache on in this process."""
    return _host is not None


def cached_arrays(kind: str, key: bytes, build: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """``build()`` (named NumPy arrays), or the arrays it gave for the same ``key`` (bytes holding every input)
    in an earlier process: kept under ``kind`` once ``enable`` ran; without it, always ``build()``. An entry
    that cannot be read is built again and replaced."""
    if _host is None:
        return build()
    import numpy as np

    path = _host / kind / f"{hashlib.sha256(key).hexdigest()[:40]}.npz"
    try:
        with np.load(path) as entry:
            return {name: entry[name] for name in entry.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError):
        pass
    arrays = build()
    from jaxcls import io

    try:
        with io.atomic_write(path) as f:
            np.savez(f, **arrays)
    except OSError as e:
        warnings.warn(f"compilation cache: cannot keep {kind} in {path.parent}: {e}", stacklevel=2)
    return arrays


@functools.cache
def code_digest() -> str:
    """A hash of every jaxcls source file (what a traced program is made of)."""
    root = Path(__file__).parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def exported_key(args: tuple) -> str:
    """What tracing a jaxcls program over ``args`` reads: jaxcls's source, the versions of JAX, jaxlib, flax
    and NumPy, JAX's settings (those that do not just say where to cache), the devices' platform and kind (a
    program is lowered for one), the arguments' tree (static settings included) and each leaf's shape, dtype,
    weak type and sharding; hashed."""
    import flax
    import jax
    import jaxlib
    import numpy as np

    leaves, tree = jax.tree.flatten(args)
    for x in leaves:
        if not (isinstance(x, jax.Array) or (isinstance(x, jax.ShapeDtypeStruct) and x.sharding is not None)):
            raise TypeError("exported: arguments must be JAX arrays on their devices (or jax.ShapeDtypeStructs with "
                            f"their sharding), got {type(x).__name__}")
    settings = sorted((k, repr(v)) for k, v in jax.config.values.items() if not any(w in k for w in _NOT_IN_KEY))
    platforms = sorted({(d.platform, d.device_kind) for x in leaves for d in x.sharding.device_set})
    parts = [code_digest(), jax.__version__, jaxlib.__version__, flax.__version__, np.__version__,
             repr(settings), repr(platforms), str(tree),
             *(f"{x.shape}|{x.dtype}|{x.weak_type}|{x.sharding!r}" for x in leaves)]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:40]


def options_key(compiler_options: dict | None) -> tuple:
    """XLA's ``compiler_options`` as a hashable key (sorted items; () for none)."""
    return tuple(sorted((compiler_options or {}).items()))


@functools.lru_cache(maxsize=32)
def _with_options(program: Callable, options: tuple) -> Callable:
    import jax

    return jax.jit(program, compiler_options=dict(options)) if options else program


def jitted(program: Callable, compiler_options: dict | None = None) -> Callable:
    """``program`` (a function or a ``jax.jit`` made without options) jitted with XLA's ``compiler_options``
    (``program`` itself where there are none), one object per program and options in a process, so that it
    compiles once. XLA takes options only at the top of a program, so a traced program that is exported or
    called inside another one stays without them (``exported`` compiles it with them)."""
    return _with_options(program, options_key(compiler_options))


def exported(jitted_program: Callable, args: tuple, kind: str, compiler_options: dict | None = None) -> Callable:
    """``jitted_program`` (a ``jax.jit`` made without options) compiled with XLA's ``compiler_options``, for calls
    of ``args``' signature (JAX arrays on their devices, or ``jax.ShapeDtypeStruct``s with their sharding: every
    later call's shapes, dtypes, shardings and static settings). Once ``enable`` ran, its traced and lowered
    program (StableHLO, ``jax.export``) is kept in ``<folder>/../exported/<kind>`` by ``exported_key``, a later
    process reads it instead of tracing it again, and it is compiled here (JAX's persistent cache: loaded), so
    that a call on a background thread (``ahead``) leaves the first real call nothing to do. Without ``enable``,
    or for a program that cannot be exported (a warning says why): ``jitted(jitted_program, compiler_options)``
    (compiled at its first call). An entry that cannot be read is made again. Only for programs whose every
    input is in ``args`` (no closed-over arrays: the key cannot see them). The options are not part of the traced
    program, so not of its key on disk. Thread-safe: a thread asking for a program another one is making waits
    for it."""
    if _host is None:
        return jitted(jitted_program, compiler_options)
    key = exported_key(args), options_key(compiler_options)
    with _making_lock:
        lock = _making.setdefault(key, threading.Lock())
    with lock:
        if key not in _exported:
            try:
                module, out_tree = _exported_module(jitted_program, args, kind, key[0])
            except Exception as e:  # (a program JAX cannot export still runs)
                warnings.warn(f"compilation cache: {kind} not exported ({type(e).__name__}: {e}); it is traced in "
                              "every process", stacklevel=2)
                _exported[key] = jitted(jitted_program, compiler_options)
            else:  # (a failure to compile, e.g. out of memory, is raised and nothing kept: a later call tries again)
                _exported[key] = _compiled(module, out_tree, args, compiler_options)
    return _exported[key]


def ahead(load: Callable[[], Any], what: str) -> Future:
    """``load()`` on a background thread (up to ``AHEAD_THREADS`` loads at once, started in the order given), e.g.
    an ``exported`` program read and compiled while the host builds a renderer or waits for the devices. An
    exception is not raised but warned about (naming ``what``): the caller then makes the program itself when
    it needs it. Returns the load's ``Future`` (its result, or None after a failure).

    Never beside a render under MuJoCo Warp's own CUDA graph capture (``WarpRenderer.loads_beside_renders``
    False: ``forward`` kinematics): a program loaded onto the GPU by another thread breaks the capture ("Warp
    CUDA error 901: operation failed due to a previous error during capture", or a crash; on an H200 a render
    loop beside a thread compiling programs failed within seconds). There the caller starts a load after its
    renders are done and waits for it before the next one (``experiments.table1.runner``: the frames of a chunk
    are done once a call that uses them is); renders in JAX's graph mode (``static``) may run beside loads."""
    global _background

    def guarded():
        try:
            return load()
        except Exception as e:
            warnings.warn(f"compilation cache: loading {what} ahead failed ({type(e).__name__}: {e}); it is made "
                          "when first called", stacklevel=2)
            return None

    with _making_lock:
        if _background is None:
            _background = ThreadPoolExecutor(max_workers=AHEAD_THREADS, thread_name_prefix="jaxcls-ahead")
    return _background.submit(guarded)


def _abstract(args: tuple) -> list:
    """``args``' leaves as ``jax.ShapeDtypeStruct``s with their sharding and weak type."""
    import jax

    return [jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding, weak_type=x.weak_type)
            for x in jax.tree.leaves(args)]


def _exported_module(jitted_program: Callable, args: tuple, kind: str, key: str) -> tuple[Any, Any]:
    """(the program's exported module, its output tree): read from ``<folder>/../exported/<kind>/<key>.bin``, or
    traced, lowered and kept there."""
    import jax
    from jax import export

    from jaxcls import io

    path = _host.parent / "exported" / kind / f"{key}.bin"  # type: ignore[union-attr]
    leaves, tree = jax.tree.flatten(args)
    abstract = _abstract(args)
    entry: dict[str, Any] | None = None
    try:
        entry = pickle.loads(path.read_bytes())
        program = export.deserialize(entry["module"])
    except FileNotFoundError:
        entry = None
    except Exception as e:  # (a damaged or foreign entry: made again)
        warnings.warn(f"compilation cache: cannot read {path} ({type(e).__name__}: {e}); tracing again", stacklevel=3)
        entry = None
    if entry is None:
        made: dict[str, Any] = {}

        def flat(*xs):
            made["out_tree"] = jax.tree.structure(out := jitted_program(*jax.tree.unflatten(tree, xs)))
            return jax.tree.leaves(out)

        # (a Pallas kernel compiled by Triton is a custom call without export's compatibility guarantee: kept
        # anyway, a kept program being keyed by the JAX and jaxlib versions)
        program = export.export(jax.jit(flat, in_shardings=[x.sharding for x in leaves]), disabled_checks=(
            export.DisabledSafetyCheck.custom_call("__gpu$xla.gpu.triton"),))(*abstract)
        entry = {"module": program.serialize(), "out_tree": made["out_tree"]}
        try:
            io.write_bytes(path, pickle.dumps(entry))
        except OSError as e:
            warnings.warn(f"compilation cache: cannot keep {kind} in {path.parent}: {e}", stacklevel=3)
    return program, entry["out_tree"]


def _compiled(program: Any, out_tree: Any, args: tuple, compiler_options: dict | None) -> Callable:
    """The exported ``program`` compiled now (JAX's persistent cache: loaded) for ``args``' signature, not at its
    first call; called with the arguments' pytree, it returns ``out_tree``'s."""
    import jax

    call = jax.jit(program.call, compiler_options=compiler_options).lower(*_abstract(args)).compile()

    def run(*call_args):
        return jax.tree.unflatten(out_tree, call(*jax.tree.leaves(call_args)))

    return run


__all__ = ["ENV", "FULL_TRACEBACKS_ENV", "MIN_COMPILE_SECONDS", "ahead", "cache_folder", "cached_arrays", "code_digest",
           "enable", "enabled", "exported", "exported_key", "jitted", "one_frame_locations", "options_key"]
