"""How the process's C allocator hands memory to tensors on the CPU.

A batched step on the CPU allocates and frees the same large temporaries every step (a few MB each
at thousands of envs). glibc's malloc gives blocks above its mmap threshold fresh pages from the
OS and returns freed memory above its trim threshold, so a step can pay again for the OS to map
and zero those pages. :func:`hold_freed_memory` raises both thresholds, so the blocks come from
malloc's heap and stay there to be reused. ``recipes/evaluate.py`` and ``recipes/benchmark.py``
call it, the benchmarks with ``--hold-memory``; the training recipes do not (what it changes, and
where it did not pay: docs/performance.md, "Memory allocator").
"""

from __future__ import annotations

import ctypes
import platform

MMAP_THRESHOLD = 256 << 20  # bytes: blocks up to this size come from the heap
TRIM_THRESHOLD = 1 << 30  # bytes: free memory at the heap's top kept for reuse, up to this much
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters (malloc.h)
_held = False


def hold_freed_memory() -> bool:
    """Set glibc's malloc to serve blocks up to ``MMAP_THRESHOLD`` bytes from its heap and keep up to
    ``TRIM_THRESHOLD`` bytes of freed memory for reuse, for the rest of the process. Returns whether
    it is set (False where the C library is not glibc, e.g. macOS or musl: nothing is changed there).

    The cost is memory: the process's resident size does not shrink back after a peak by up to
    ``TRIM_THRESHOLD``. Call it first in a script that steps big batches on the CPU."""
    global _held
    if _held:
        return True
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    libc = ctypes.CDLL(None)
    _held = bool(libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    return _held


def freed_memory_held() -> bool:
    """Whether :func:`hold_freed_memory` has set the allocator in this process."""
    return _held
