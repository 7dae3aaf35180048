"""``allocator.retain_freed_memory``: a freed block is reused, not page-faulted back in (glibc only)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from jaxcls import allocator

# Run apart from the suite's process, whose allocator settings other tests (the CLI's) may have changed.
_PROBE = """
import ctypes, resource
from jaxcls import allocator
libc = ctypes.CDLL("libc.so.6")
libc.malloc.restype = ctypes.c_void_p
libc.free.argtypes = [ctypes.c_void_p]
libc.mallopt(-3, 128 * 1024)  # glibc's initial mmap threshold, held fixed: the control

def faults(n=64 << 20):
    p = libc.malloc(n); ctypes.memset(p, 1, n); libc.free(p)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    p = libc.malloc(n); ctypes.memset(p, 1, n); libc.free(p)
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

control = faults()
taken = allocator.retain_freed_memory()
print(control, int(taken), faults())
"""


@pytest.mark.skipif(allocator._libc() is None, reason="glibc only")
def test_freed_block_is_reused_without_page_faults():
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, check=True).stdout
    control, taken, retained = map(int, out.split())
    assert taken == 1
    assert control > 1000  # 64 MB mapped afresh: one fault per 4 KB page (fewer with huge pages, still many)
    assert retained < control // 100


def test_refuses_a_nonpositive_limit():
    with pytest.raises(ValueError, match="limit_bytes"):
        allocator.retain_freed_memory(0)
