"""JAX's persistent compilation cache for jaxcls's commands and experiments.

A short run spends most of its time compiling (a 10-move ``jaxcls demo``: ~34 s of ~50 s on a 2-core CPU).
With the cache on, every compiled XLA program is also written to a folder, and a later process that
compiles the same program (same code, shapes, settings, JAX version and device) loads it instead.

The folder: ``$JAXCLS_CACHE_DIR`` if set (``off`` turns the cache off), else ``$XDG_CACHE_HOME/jaxcls/xla``
(``~/.cache/jaxcls/xla``). Delete it to start cold; JAX keys entries by everything that changes a program,
so a stale entry is never used for another one. The ``jaxcls`` commands and ``experiments/table1.py`` call
``enable`` at start-up; a notebook or script of your own calls it once, before its first jit.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

ENV = "JAXCLS_CACHE_DIR"
OFF = ("off", "none", "0", "false", "")
# Programs that compile faster than this are not written (they cost more to load than to build again).
MIN_COMPILE_SECONDS = 0.1


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
    return target


__all__ = ["ENV", "MIN_COMPILE_SECONDS", "cache_folder", "enable"]
