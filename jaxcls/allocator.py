"""Keep freed memory in the process: a move's buffers are reused instead of page-faulted back in.

XLA's CPU runtime allocates each call's outputs and temporaries afresh: one move of the episode touches
tens of MB of new buffers (the 128^3 TSDF alone is 16 MB). glibc hands blocks above its mmap threshold
(128 KB, raised dynamically to at most 32 MB) straight back to the kernel when they are freed and trims
the free top of its heaps, so the next move page-faults the same memory in again (~4,000 faults per
16 MB). On the 2-core CPU that is a third of a move's time (``benchmarks/move.py --allocator``:
BENCHMARKS.md). ``retain_freed_memory`` raises both thresholds so that the blocks stay in the process and
are reused; the resident size stays where the peak of one move puts it.

It changes a process-wide setting, so nothing calls it on import: ``jaxcls``'s commands and the
benchmark and experiment scripts call it at start-up; a notebook or a script of your own may call it
once. It does nothing outside glibc (macOS, musl), where it returns False.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

# mallopt(3) parameters (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


@functools.lru_cache(maxsize=1)
def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        libc = ctypes.CDLL(name)
    except OSError:
        return None
    # glibc only: musl and macOS have no mallopt thresholds.
    return libc if hasattr(libc, "gnu_get_libc_version") else None


def retain_freed_memory(limit_bytes: int = 256 << 20) -> bool:
    """Serve blocks below ``limit_bytes`` from the heap and keep up to ``limit_bytes`` of freed memory in
    the process (glibc's ``M_MMAP_THRESHOLD`` and ``M_TRIM_THRESHOLD``). True when glibc took both."""
    if limit_bytes <= 0:
        raise ValueError(f"retain_freed_memory: limit_bytes must be > 0, got {limit_bytes}")
    libc = _libc()
    if libc is None:
        return False
    limit = ctypes.c_int(min(int(limit_bytes), 2**31 - 1))
    return bool(libc.mallopt(_M_MMAP_THRESHOLD, limit)) & bool(libc.mallopt(_M_TRIM_THRESHOLD, limit))


__all__ = ["retain_freed_memory"]
