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
from collections.abc import Iterable

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
    """A file over the size a reader takes (refused from its size before it is read, or as
    soon as it grows past it while read)."""


#: Bytes read at a time from a file that has grown since it was looked at.
_READ_STEP = 1024**2


def read_regular(path: str | os.PathLike, max_bytes: int) -> bytes:
    """The bytes of the regular file at ``path``, of at most ``max_bytes``: the files read
    whole (traces, floor plans, walk plans, name lists). One read of the size ``fstat`` gives
    (no buffer of ``max_bytes`` is taken); a file grown since is read on in steps, never past
    the limit. Raises :class:`NotRegularFile` (a FIFO, device or a link to one: nothing is
    read), :class:`FileTooLarge` or the ``OSError`` of opening or reading it; all are
    ``OSError``."""
    fd, st = open_regular(path)
    with open(fd, "rb") as fh:
        if st.st_size > max_bytes:
            raise FileTooLarge(f"file is {st.st_size} bytes, over the {max_bytes}-byte limit")
        data = fh.read(st.st_size + 1)  # one read of the expected size (+1: grown?)
        if len(data) <= st.st_size:
            return data
        parts, total = [data], len(data)
        while total <= max_bytes:
            more = fh.read(min(_READ_STEP, max_bytes + 1 - total))
            if not more:
                break
            parts.append(more)
            total += len(more)
        if total > max_bytes:
            raise FileTooLarge(f"file grew past the {max_bytes}-byte limit while read")
        return b"".join(parts)


def path_list(paths: str | os.PathLike | Iterable[str | os.PathLike]) -> list:
    """``paths`` as a list: one path given alone (a ``str`` or path-like) is a list of one,
    not its characters (``ingest("survey/F1", store)`` searched ``s``, ``u``, ... and
    ``/``, the whole file system)."""
    if isinstance(paths, (str, bytes, os.PathLike)):
        return [paths]
    return list(paths)
