"""Deterministic serialization: the same objects always give the same bytes."""

from __future__ import annotations

import io
import json

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq


def json_bytes(obj: object, *, compact: bool = False) -> bytes:
    """UTF-8 JSON (keys in insertion order, no NaN), ``\\n``-terminated.

    ``compact`` writes one line without spaces (map files); otherwise indented by one space.
    """
    if compact:
        text = json.dumps(obj, ensure_ascii=False, allow_nan=False, separators=(",", ":"))
    else:
        text = json.dumps(obj, ensure_ascii=False, allow_nan=False, indent=1)
    return (text + "\n").encode("utf-8")


def parquet_bytes(df: pd.DataFrame) -> bytes:
    """Parquet file bytes of ``df`` (no index, zstd, byte-stream-split floats; deterministic
    for a given pyarrow version)."""
    table = pa.Table.from_pandas(df, preserve_index=False)
    floats = [f.name for f in table.schema if pa.types.is_floating(f.type)]
    buf = io.BytesIO()
    pq.write_table(table, buf, compression="zstd", compression_level=9,
                   use_byte_stream_split=floats or False, use_dictionary=[
                       f.name for f in table.schema
                       if pa.types.is_string(f.type) or pa.types.is_large_string(f.type)
                       or pa.types.is_dictionary(f.type)] or False,
                   write_statistics=False, store_schema=True)
    return buf.getvalue()
