"""Returning freed memory to the operating system between the phases of a long job.

Reading a floor walk by walk allocates and frees many medium-sized buffers. glibc's allocator
keeps freed heap pages (and raises its mmap threshold after large frees, so later large arrays
land in that fragmented heap too), and Arrow's pool keeps its own; the process then holds
hundreds of MB it no longer uses, which the next phase's peak adds to. On the 10x floor of
``benchmarks/build_memory.py`` the Wi-Fi observation table is 318 MB but the process had grown
by 760 MB after reading it; a trim gives back 360 MB.
"""

from __future__ import annotations

import ctypes
import sys
from functools import cache

__all__ = ["release_free_memory"]


@cache
def _malloc_trim():
    """glibc's ``malloc_trim``, or None (not Linux, or a libc without it, e.g. musl)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        trim = ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def release_free_memory() -> None:
    """Give freed heap memory back to the OS (glibc ``malloc_trim``, Arrow's pool). Harmless
    where neither applies."""
    import pyarrow as pa

    pa.default_memory_pool().release_unused()
    trim = _malloc_trim()
    if trim is not None:
        trim(0)
