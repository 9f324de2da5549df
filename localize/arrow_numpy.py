"""Numeric Arrow columns as numpy arrays, read from their buffers.

pyarrow's own conversions (``Array.to_numpy``, ``np.asarray(array)``, ``pq.read_table``)
import pandas on first use (pyarrow 26), which costs the runtime half a second and breaks its
promise of numpy and pyarrow only (issue #7; ``tests/test_localize_runtime.py`` checks it).
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

__all__ = ["numeric_column"]


def _numpy_dtype(typ: pa.DataType) -> np.dtype:
    if pa.types.is_integer(typ):
        return np.dtype(f"{'i' if pa.types.is_signed_integer(typ) else 'u'}{typ.bit_width // 8}")
    if pa.types.is_floating(typ) and typ.bit_width in (32, 64):
        return np.dtype(f"f{typ.bit_width // 8}")
    raise TypeError(f"not a numeric Arrow column: {typ}")


def numeric_column(column: pa.ChunkedArray | pa.Array) -> NDArray:
    """An integer or floating-point column as a new numpy array of its own type, shape
    ``(len(column),)``; with nulls, float64 with NaN for them (as ``to_numpy`` gives)."""
    chunks = column.chunks if isinstance(column, pa.ChunkedArray) else [column]
    dtype = _numpy_dtype(column.type)
    parts = []
    for chunk in chunks:
        n = len(chunk)
        if n == 0:
            continue
        validity, data = chunk.buffers()[:2]
        values = np.frombuffer(data, dtype=dtype, count=n, offset=chunk.offset * dtype.itemsize)
        if chunk.null_count:
            bits = np.unpackbits(np.frombuffer(validity, dtype=np.uint8), bitorder="little")
            values = np.where(bits[chunk.offset:chunk.offset + n].astype(bool),
                              values.astype(np.float64), np.nan)
        parts.append(values)
    if not parts:
        return np.empty(0, dtype=dtype)
    if any(p.dtype != parts[0].dtype for p in parts):  # nulls in some chunks only
        parts = [p.astype(np.float64) for p in parts]
    return np.concatenate(parts)
