"""Opening a file for reading only if it is a regular file.

A FIFO would block the reader until a writer comes, a device such as ``/dev/zero`` never ends,
and either can sit where a trace or a bundle member was expected (put there, or swapped in
between a check and the read). :func:`open_regular` looks at the path before opening it, opens
it without blocking (so a FIFO swapped in meanwhile does not wait for a writer), and looks at
what it opened before anything is read.
"""

from __future__ import annotations

import os
import stat

_OPEN_FLAGS = os.O_RDONLY | getattr(os, "O_BINARY", 0) | getattr(os, "O_NONBLOCK", 0)


class NotRegularFile(OSError):
    """The path is not a regular file (a FIFO, socket or device, or a link to one)."""


def open_regular(path: str | os.PathLike) -> tuple[int, os.stat_result]:
    """A file descriptor (blocking, for reading) of the regular file at ``path`` and its
    ``fstat``. The caller closes it. Raises :class:`NotRegularFile`, or the ``OSError`` of
    ``stat``/``open`` (missing file, no permission)."""
    if not stat.S_ISREG(os.stat(path).st_mode):
        raise NotRegularFile(f"not a regular file: {path}")
    fd = os.open(path, _OPEN_FLAGS)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):  # replaced since os.stat
            raise NotRegularFile(f"not a regular file: {path}")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd, st


class FileTooLarge(OSError):
    """A file over the size a reader takes (refused from its size before it is read)."""


def read_regular(path: str | os.PathLike, max_bytes: int) -> bytes:
    """The bytes of the regular file at ``path``, of at most ``max_bytes``: for the small
    files the commands read whole (floor plans, walk plans, name lists). Raises
    :class:`NotRegularFile` (a FIFO, device or a link to one: nothing is read),
    :class:`FileTooLarge` or the ``OSError`` of opening it; all are ``OSError``."""
    fd, st = open_regular(path)
    with open(fd, "rb") as fh:
        if st.st_size > max_bytes:
            raise FileTooLarge(f"{path}: {st.st_size} bytes, over the {max_bytes}-byte limit")
        data = fh.read(max_bytes + 1)
    if len(data) > max_bytes:  # grown since fstat
        raise FileTooLarge(f"{path}: over the {max_bytes}-byte limit")
    return data
