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
import ctypes.util
import sys

__all__ = ["release_free_memory"]


def _libc_trim():
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return libc.malloc_trim
    except (OSError, AttributeError):  # not glibc (e.g. musl): nothing to trim
        return None


_TRIM = _libc_trim()


def release_free_memory() -> None:
    """Give freed heap memory back to the OS (glibc ``malloc_trim``, Arrow's pool). Harmless
    where neither applies."""
    try:
        import pyarrow as pa

        pa.default_memory_pool().release_unused()
    except ImportError:  # pragma: no cover - pyarrow is a dependency
        pass
    if _TRIM is not None:
        _TRIM(0)
