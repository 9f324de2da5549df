"""Reading trace files as bytes: plain text or gzip (detected by magic bytes), size-capped.

A truncated gzip stream (a file cut short) is an error in strict mode; in lenient mode its
readable prefix is kept and a note says what was wrong. A damaged stream (a flipped or lost
byte: invalid deflate data, or a checksum or length that does not match the text) is refused
in both modes, as ``gzip -d`` refuses it: inflating goes on past a flipped byte with garbage
(or with one wrong value, caught by the checksum only) before it fails, and where the text
stops being what was written cannot be told, so none of it can be trusted.
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

    A truncated gzip stream raises in strict mode; in lenient mode the readable prefix is
    returned with a note (its last, partial line is then reported as bad). A damaged stream
    raises in both modes (module docstring).
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
            raise SurveyFormatError(
                f"damaged gzip stream ({err}): the text it inflates to is not what was "
                "written, and where it stops being so cannot be told, so none of it is kept "
                "(a file that is only cut short keeps its readable part)",
                path=str(path), reason="gzip") from err
        total += len(out)
        chunks.append(out)
        if total > max_bytes:
            raise SurveyFormatError(f"decompresses to over {max_bytes} bytes, refused",
                                    path=str(path), reason="too_large")
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
