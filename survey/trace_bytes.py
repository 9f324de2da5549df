"""Reading trace files as bytes: plain text or gzip (detected by magic bytes), size-capped.

A damaged or truncated gzip stream is an error in strict mode; in lenient mode the readable
prefix is kept and a note says what was wrong.
"""

from __future__ import annotations

import os
import zlib
from pathlib import Path

from .errors import SurveyFormatError

try:  # Intel ISA-L inflates about twice as fast as zlib: same streams, same results
    from isal import isal_zlib as _zlib
except ImportError:  # pragma: no cover - isal is a declared dependency
    _zlib = zlib

#: Refuse traces whose decompressed text would exceed this many bytes (resource limit).
MAX_TRACE_BYTES = 2 * 1024**3


def read_trace_bytes(path: str | os.PathLike, *, strict: bool = False,
                     max_bytes: int = MAX_TRACE_BYTES) -> tuple[bytes, str | None]:
    """Return the trace text as bytes (gunzipped if needed) and a problem note or ``None``.

    A truncated or damaged gzip stream raises in strict mode; in lenient mode the readable
    prefix is returned with a note (its last, partial line is then reported as bad).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise SurveyFormatError(f"cannot read: {err.strerror or err}", path=str(path),
                                reason="io") from err
    if raw[:2] != b"\x1f\x8b":
        if len(raw) > max_bytes:
            raise SurveyFormatError(f"file is {len(raw)} bytes, over the {max_bytes}-byte limit",
                                    path=str(path), reason="too_large")
        return raw, None
    chunks: list[bytes] = []
    total = 0
    note = None
    data = raw
    while data:
        dec = _zlib.decompressobj(wbits=31)
        try:
            out = dec.decompress(data, max_bytes + 1 - total)
        except (zlib.error, _zlib.error) as err:
            note = f"damaged gzip stream ({err})"
            out = _salvage(data, max_bytes + 1 - total)
        total += len(out)
        chunks.append(out)
        if total > max_bytes:
            raise SurveyFormatError(f"decompresses to over {max_bytes} bytes, refused",
                                    path=str(path), reason="too_large")
        if note:
            break
        if not dec.eof:
            note = "truncated gzip stream"
            break
        data = dec.unused_data
        if not data.strip(b"\0"):  # zero padding after the last stream (block devices, tar)
            break
        if data[:2] != b"\x1f\x8b":
            note = "trailing garbage after gzip stream"
            break
    if note and strict:
        raise SurveyFormatError(note, path=str(path), reason="gzip")
    return b"".join(chunks), note


def _salvage(data: bytes, limit: int) -> bytes:
    """Decompress as much of a damaged gzip member as possible, in small steps."""
    dec = zlib.decompressobj(wbits=31)  # the standard one: it can copy its state
    out = []
    n = 0
    step = 1 << 14
    for i in range(0, len(data), step):
        before = dec.copy()
        try:
            piece = dec.decompress(data[i:i + step], max(limit - n, 1))
        except zlib.error:
            # again byte by byte from the state before this chunk: keep what precedes the
            # damage (a bad checksum in the trailer loses nothing)
            dec, pieces = before, []
            for j in range(i, min(i + step, len(data))):
                try:
                    pieces.append(dec.decompress(data[j:j + 1], max(limit - n, 1)))
                except zlib.error:
                    break
            out.append(b"".join(pieces))
            break
        out.append(piece)
        n += len(piece)
        if n >= limit:
            break
    return b"".join(out)
