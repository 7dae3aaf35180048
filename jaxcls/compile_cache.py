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
"""

from __future__ import annotations

import hashlib
import os
import warnings
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

ENV = "JAXCLS_CACHE_DIR"
OFF = ("off", "none", "0", "false", "")
# Programs that compile faster than this are not written (they cost more to load than to build again).
MIN_COMPILE_SECONDS = 0.1
_host: Path | None = None  # where ``cached_arrays`` keeps its entries (set by ``enable``)


def cache_folder() -> Path | None:
    """The folder ``enable`` uses by default (None: ``$JAXCLS_CACHE_DIR`` says off)."""
    value = os.environ.get(ENV)
    if value is not None:
        return None if value.strip().lower() in OFF else Path(value).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jaxcls" / "xla"


def enable(folder: str | Path | None = None, min_compile_seconds: float = MIN_COMPILE_SECONDS) -> Path | None:
    """Turn JAX's persistent compilation cache on in ``folder`` (default ``cache_folder()``). Returns the
    folder, or None when the cache is off (``$JAXCLS_CACHE_DIR=off``) or the folder cannot be written (a
    warning says why; the run goes on, compiling as usual)."""
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


__all__ = ["ENV", "MIN_COMPILE_SECONDS", "cache_folder", "cached_arrays", "enable"]
