"""Reading trace files as bytes: plain text or gzip (detected by magic bytes), size-capped.

A truncated gzip stream (a file cut short) is an error in strict mode; in lenient mode its
readable prefix is kept and a note says what was wrong. A damaged stream (a flipped or lost
byte: invalid deflate data, or a checksum or length that does not match the text) is refused
in both modes, as ``gzip -d`` refuses it: inflating goes on past a flipped byte with garbage
(or with one wrong value, caught by the checksum only) before it fails, and where the text
stops being what was written cannot be told, so none of it can be trusted.

Resource limits, checked before the memory is taken: only a regular file is read (a FIFO, a
socket, a device such as ``/dev/zero``, or a link to one, would block or never end), and it is
looked at (``stat``) before it is opened, so opening a FIFO cannot block; a file over
``max_bytes`` on disk is refused before it is read, and no read goes past ``max_bytes`` (a
file growing while read is refused too); gzip is inflated in steps of at most
``_OUT_STEP`` bytes of text, from at most ``_IN_STEP`` compressed bytes at a time, and
refused as soon as the running total passes ``max_bytes``. A stream that inflates to more than
``_SUSPECT_BYTES`` at over ``_SUSPECT_RATIO`` times its compressed size (a gzip bomb: real
traces inflate about 6 times) is first only measured, its text thrown away step by step, and
inflated again to be kept only if it is within the limit: a bomb costs about
``_SUSPECT_BYTES`` of memory, not ``max_bytes``, before it is refused.

Text saved as UTF-16 or UTF-32 is refused whole (:func:`check_not_utf16_or_32`), in both modes.
"""

from __future__ import annotations

import contextlib
import os
import zlib
from collections.abc import Iterator
from pathlib import Path

from .errors import SurveyFormatError
from .publish import file_sha256_and_size
from .regular_files import FileTooLarge, NotRegularFile, read_regular

try:  # Intel ISA-L inflates about twice as fast as zlib: same streams, same results
    from isal import isal_zlib as _zlib
except ImportError:  # pragma: no cover - isal is a declared dependency
    _zlib = zlib

#: Refuse traces whose decompressed text would exceed this many bytes (resource limit).
MAX_TRACE_BYTES = 2 * 1024**3

#: Text bytes inflated per step at most (a whole ILC trace is one step: no copy to join).
_OUT_STEP = 16 * 1024**2
#: Compressed bytes handed to the decompressor at a time (bounds the copies it makes of the
#: input it has not used: a file of many small gzip members is not copied once per member).
_IN_STEP = 1024**2
#: Inflated text past which a stream inflating over ``_SUSPECT_RATIO`` times its compressed
#: size is measured before it is kept (module docstring).
_SUSPECT_BYTES = 64 * 1024**2
_SUSPECT_RATIO = 50


def read_trace_bytes(path: str | os.PathLike, *, strict: bool = False,
                     max_bytes: int = MAX_TRACE_BYTES) -> tuple[bytes, str | None]:
    """Return the trace text as bytes (gunzipped if needed) and a problem note or ``None``.

    A truncated gzip stream raises in strict mode; in lenient mode the readable prefix is
    returned with a note (its last, partial line is then reported as bad). A damaged stream
    raises in both modes, and so do a file that is not a regular file, one whose size on
    disk or text is over ``max_bytes`` (module docstring) and UTF-16 or UTF-32 text.
    """
    path = Path(path)
    raw = _read_capped(path, max_bytes)
    if raw[:2] != b"\x1f\x8b":
        check_not_utf16_or_32(raw, path)
        return raw, None
    chunks, note = _inflate(raw, path, max_bytes)
    if note and strict:
        raise SurveyFormatError(note, path=str(path), reason="gzip")
    text = b"".join(chunks)  # one chunk (the usual case) is returned without a copy
    check_not_utf16_or_32(text, path)  # its start: of every member, not the first's alone
    return text, note


#: Byte-order marks of the text encodings refused (UTF-32's first: UTF-32LE's begins with
#: UTF-16LE's).
_WIDE_MARKS = ((b"\xff\xfe\x00\x00", "UTF-32", "little"), (b"\x00\x00\xfe\xff", "UTF-32", "big"),
               (b"\xff\xfe", "UTF-16", "little"), (b"\xfe\xff", "UTF-16", "big"))
#: Bytes of a text's start looked at for a wide encoding without a byte-order mark.
_WIDE_HEAD_BYTES = 4096


def wide_encoding(head: bytes) -> tuple[str, str] | None:
    """``(encoding, byte order)`` when ``head`` (a text, of which the first 4 KiB are read) is
    UTF-16 or UTF-32, else None.

    A byte-order mark says so; without one, the NUL bytes do. UTF-8 text has none, while in
    UTF-16 each ASCII character (a trace's every character but those of its names) has a NUL
    high byte and few characters a NUL low byte; in UTF-32 the two high bytes of each character
    are NUL (the top one always, the next below U+10000) and few low bytes are. Shares, not every
    character, decide: a site name in Chinese at the start still reads as UTF-16."""
    for mark, encoding, order in _WIDE_MARKS:
        if head.startswith(mark):
            return encoding, order
    head = head[:min(len(head), _WIDE_HEAD_BYTES) // 4 * 4]
    if len(head) < 16:
        return None

    def nul_share(offset: int, step: int) -> float:
        part = head[offset::step]
        return part.count(0) / len(part)

    q = [nul_share(i, 4) for i in range(4)]  # by byte of a 4-byte character
    h = [nul_share(i, 2) for i in range(2)]  # by byte of a 2-byte character
    # UTF-32: the top byte always NUL, the next for all but the rare characters beyond
    # U+FFFF (an emoji in a name)
    if q[3] == 1 and q[2] >= 0.9 and q[0] < 0.05:
        return "UTF-32", "little"
    if q[0] == 1 and q[1] >= 0.9 and q[3] < 0.05:
        return "UTF-32", "big"
    if h[1] >= 0.5 and h[0] < 0.05:  # at least half the characters ASCII
        return "UTF-16", "little"
    if h[0] >= 0.5 and h[1] < 0.05:
        return "UTF-16", "big"
    return None


def check_not_utf16_or_32(text: bytes, path: str | os.PathLike) -> None:
    """A SurveyFormatError naming ``path`` when ``text`` (its start is enough) is UTF-16 or
    UTF-32 (:func:`wide_encoding`; Windows tools save "Unicode" text as UTF-16). Read as UTF-8
    every line of it was a bad line, and the message ("timestamp is not an integer of
    milliseconds") did not say why."""
    found = wide_encoding(text)
    if found is not None:
        encoding, order = found
        raise SurveyFormatError(f"{encoding} text ({order}-endian); indoormap reads UTF-8: "
                                f"convert it (e.g. iconv -f {encoding} -t UTF-8)",
                                path=str(path), reason="encoding")


def not_regular(path: str | os.PathLike) -> SurveyFormatError:
    """The error for a path that is not a regular file: a folder where one file was wanted,
    or a FIFO, socket or device."""
    if os.path.isdir(path):
        return SurveyFormatError("a folder, not a trace file: give one .txt or .txt.gz file "
                                 "(iter_traces(find_trace_files([folder])) reads a folder's)",
                                 path=str(path), reason="not_regular")
    return SurveyFormatError("not a regular file (a FIFO, socket or device, or a link to one, "
                             "could block or never end), not read", path=str(path),
                             reason="not_regular")


@contextlib.contextmanager
def _read_errors(path: str | os.PathLike) -> Iterator[None]:
    """Raise what opening or reading ``path`` fails with as a :class:`SurveyFormatError`."""
    try:
        yield
    except NotRegularFile as err:
        raise not_regular(path) from err
    except FileTooLarge as err:
        raise SurveyFormatError(str(err), path=str(path), reason="too_large") from err
    except OSError as err:
        raise SurveyFormatError(f"cannot read: {err.strerror or err}", path=str(path),
                                reason="io") from err


def trace_file_sha256(path: str | os.PathLike) -> tuple[str, int]:
    """Hex sha256 and size (bytes) of a trace file as stored (compressed or not); raises
    :class:`SurveyFormatError` naming the file for one that cannot be read or is not a
    regular file (hashing a FIFO would block, a device never end). The size is that of the
    bytes hashed, not of a second look at the path."""
    with _read_errors(path):
        return file_sha256_and_size(path)


def _read_capped(path: Path, max_bytes: int) -> bytes:
    """The bytes of a regular file of at most ``max_bytes``, refused from its size before
    any is read (:func:`~survey.regular_files.read_regular`: a FIFO is not waited on)."""
    with _read_errors(path):
        return read_regular(path, max_bytes)


def _inflate(raw: bytes, path: Path, max_bytes: int, *, keep: bool = True,
             screen: bool = True) -> tuple[list[bytes], str | None]:
    """The text of the gzip members in ``raw``, as chunks, and a note (truncated stream,
    trailing garbage) or ``None``; raises for a damaged stream or a text over ``max_bytes``.

    ``keep=False`` only measures (no chunks kept); ``screen`` measures first a stream that
    looks like a bomb (module docstring)."""
    view = memoryview(raw)
    n = len(raw)
    pos = 0  # compressed bytes handed to a decompressor (minus what it gave back)
    chunks: list[bytes] = []
    total = 0
    while True:  # one gzip member per round
        dec = _zlib.decompressobj(wbits=31)
        feed: bytes | memoryview = b""
        while True:
            if not feed and pos < n:
                feed = view[pos:pos + _IN_STEP]
                pos += len(feed)
            try:
                out = dec.decompress(feed, min(_OUT_STEP, max_bytes + 1 - total))
            except (zlib.error, _zlib.error) as err:
                raise SurveyFormatError(
                    f"damaged gzip stream ({err}): the text it inflates to is not what was "
                    "written, and where it stops being so cannot be told, so none of it is "
                    "kept (a file that is only cut short keeps its readable part)",
                    path=str(path), reason="gzip") from err
            if out:
                total += len(out)
                if total > max_bytes:
                    raise SurveyFormatError(f"decompresses to over {max_bytes} bytes, refused",
                                            path=str(path), reason="too_large")
                if keep:
                    chunks.append(out)
                    if screen and total > _SUSPECT_BYTES and total > _SUSPECT_RATIO * pos:
                        chunks.clear()
                        del out  # nothing of it held while measuring
                        _inflate(raw, path, max_bytes, keep=False)  # raises if over the limit
                        return _inflate(raw, path, max_bytes, screen=False)
            if dec.eof:
                pos -= len(dec.unused_data)  # the next member starts there
                break
            tail = dec.unconsumed_tail
            if not out and len(tail) == len(feed) and (feed or pos >= n):
                break  # no output, no input used: the input ends before the stream does
            feed = tail
        if not dec.eof:
            return chunks, "truncated gzip stream"
        if raw.count(b"\0", pos) == n - pos:
            return chunks, None  # zero padding after the last stream (block devices, tar)
        if raw[pos:pos + 2] != b"\x1f\x8b":
            return chunks, "trailing garbage after gzip stream"
