"""Fast reader for survey traces (``.txt`` and ``.txt.gz``), see ``docs/trace_format.md``.

The reader is columnar and works on batches of files at once: the texts of several traces are
concatenated and scanned by a compiled pass (:mod:`survey.line_scan`) that splits lines,
classifies every line's record type and parses the all-numeric records (sensors, waypoints) in
plain decimal spelling on the spot; the other lines of each value layout (Wi-Fi, beacons, and
numeric lines in any other spelling) are handed to pyarrow's CSV parser as one block. Only a
block that fails this fast path (a non-numeric value, a wrong field count, a stray carriage
return, invalid UTF-8) is re-read line by line to find the bad lines. :func:`iter_traces`
overlaps the scan of one batch with the table building of the previous one (threads; the scan
and pyarrow release the GIL) and inflates files ahead in a third thread.

Every line ends up in exactly one count of its trace's :class:`~survey.trace_format.ParseReport`:
header, blank, parsed record (per type), skipped undocumented type, or bad line (per reason).
Lenient mode (default) skips bad lines; strict mode raises :class:`SurveyFormatError` naming the
file and line of the first bad line.

Rules applied after parsing (counted in ``report.dropped``):

- ``duplicate_timestamp``: a sensor row whose timestamp repeats an earlier row of the same stream
  in the same trace; the first row in file order is kept.
- ``duplicate_bssid_in_scan``: a scan that lists a BSSID more than once keeps the freshest row
  (latest last-seen time), then the strongest RSSI, then the first in file order.
- ``duplicate_beacon``, ``duplicate_waypoint``: a beacon or waypoint row that repeats an earlier
  row of the same trace in every value (a file joined to a copy of itself) is dropped.

And one that keeps its rows (counted there too): ``wifi_last_seen_other_clock``, a Wi-Fi row
last seen more than :data:`~survey.trace_format.MAX_WIFI_AGE_MS` before its scan has its age
taken as 0 (unknown).
"""

from __future__ import annotations

import os
import re
from collections import Counter, deque
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

# one RSSI range (dBm) for the reader, the radio build and a bundle's radio tables
from localize.bundle import RSSI_RANGE_DBM, rssi_reading

from .errors import SurveyFormatError
from .regular_files import path_list
from .trace_bytes import MAX_TRACE_BYTES, not_regular, read_trace_bytes
from .trace_format import (
    BLE_COLUMNS,
    BLE_DTYPES,
    CALIBRATED_STREAMS,
    MAX_FROM_MEDIAN_TIME_MS,
    MAX_WIFI_AGE_MS,
    MAX_WIFI_SEEN_AFTER_SCAN_MS,
    SENSOR_COLUMNS,
    SENSOR_DTYPES,
    SENSOR_STREAMS,
    STREAM_NAMES,
    UNCALIBRATED_STREAMS,
    VALUE_COUNTS,
    WAYPOINT_COLUMNS,
    WAYPOINT_DTYPES,
    WAYPOINT_LIMIT_M,
    sensor_limit,
    WIFI_COLUMNS,
    WIFI_DTYPES,
    ParseReport,
    Trace,
    TraceHeader,
    empty_table,
    far_from_median_time,
    stream_category,
)
from .line_scan import TOKEN_WIDTH as _TOKEN_WIDTH
from .line_scan import BAD_TIMESTAMP, BAD_TOKEN, BLANK, HEADER, NO_TAB, OTHER_TOKEN, \
    ScanResult, best_of_runs, canonical_macs, scan_lines
from .trace_header import parse_header

#: How many ``file:line: reason`` messages a report keeps.
MAX_MESSAGES = 20
#: Text bytes parsed together by :func:`iter_traces` (bounds memory; larger files go alone).
BATCH_BYTES = 8 * 1024**2

_INT_LIMIT = 2**53  # integers beyond this cannot be values of this format
# Finite float64 values at or beyond this become infinite as float32 (round to nearest even).
_FLOAT32_LIMIT = 2.0**128 - 2.0**103
# Number spellings pyarrow's parser accepts and Python's int()/float() do not. The line-by-line
# fallback accepts them too, so that a line parses the same whichever path reads it.
_ARROW_HEX_INT = re.compile(r" *0[xX]([0-9a-fA-F]{1,16}) *")
# and spellings Python takes that pyarrow does not: only ASCII, no '_' grouping, no '+' on an
# integer, spaces as the only white space
_ARROW_DEC_INT = re.compile(r" *-?[0-9]+ *")
_PYTHON_ONLY_FLOAT = re.compile(r"[^ -~]|_")
_ARROW_NAN = re.compile(r" *[+-]?nan\([0-9A-Za-z_]*\) *", re.IGNORECASE)

# Value columns per record type: (name, kind) with kind "f" float, "i" integer, "s" string.
_SPECS: dict[str, list[tuple[str, str]]] = {
    **{k: [("x", "f"), ("y", "f"), ("z", "f"), ("accuracy", "i")] for k in CALIBRATED_STREAMS},
    **{k: [("x", "f"), ("y", "f"), ("z", "f"), ("bx", "f"), ("by", "f"), ("bz", "f"),
           ("accuracy", "i")] for k in UNCALIBRATED_STREAMS},
    "TYPE_WIFI": [("ssid", "s"), ("bssid", "s"), ("rssi_dbm", "i"), ("freq_mhz", "i"),
                  ("last_seen_ms", "i")],
    "TYPE_BEACON": [("uuid", "s"), ("major", "i"), ("minor", "i"), ("tx_power_dbm", "i"),
                    ("rssi_dbm", "i"), ("distance_m", "f"), ("mac", "s"), ("last_seen_ms", "i")],
    "TYPE_WAYPOINT": [("x_m", "f"), ("y_m", "f")],
}
assert all(len(v) == VALUE_COUNTS[k] for k, v in _SPECS.items())
_ARROW_KIND = {"f": pa.float64(), "i": pa.int64(), "s": pa.string()}

# Record types with the same value layout are parsed together as one block ("group").
_TYPE_LIST: list[str] = [*CALIBRATED_STREAMS, *UNCALIBRATED_STREAMS, "TYPE_WIFI",
                         "TYPE_BEACON", "TYPE_WAYPOINT"]
#: Per record type of ``_TYPE_LIST``: the largest plausible |value| (inf for non-sensors).
SENSOR_LIMITS = np.array([sensor_limit(SENSOR_STREAMS.get(t, ""))[0] for t in _TYPE_LIST])
_SENSOR_UNIT = [sensor_limit(SENSOR_STREAMS.get(t, ""))[1] for t in _TYPE_LIST]
_GROUP_OF_INDEX = np.array([0] * len(CALIBRATED_STREAMS) + [1] * len(UNCALIBRATED_STREAMS)
                           + [2, 3, 4], dtype=np.int32)
_GROUP_SPECS = [_SPECS["TYPE_ACCELEROMETER"], _SPECS["TYPE_ACCELEROMETER_UNCALIBRATED"],
                _SPECS["TYPE_WIFI"], _SPECS["TYPE_BEACON"], _SPECS["TYPE_WAYPOINT"]]
# All-numeric layouts are parsed during the line scan itself (plain spellings; see line_scan).
_GROUP_LAYOUTS = [None if any(k == "s" for _, k in spec) else "".join(k for _, k in spec)
                  for spec in _GROUP_SPECS]
_STREAM_CODE_OF_TYPE = np.array([STREAM_NAMES.index(SENSOR_STREAMS[k]) if k in SENSOR_STREAMS
                                 else -1 for k in _TYPE_LIST], dtype=np.int16)
# Row k keeps the first k bytes of a token window.
_PREFIX_MASKS = np.where(np.arange(_TOKEN_WIDTH)[None, :] < np.arange(_TOKEN_WIDTH + 1)[:, None],
                         np.uint8(255), np.uint8(0)).astype(np.uint8)
_HASH_MULT = np.array([0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9,
                       0x27D4EB2F165667C5, 0xFF51AFD7ED558CCD, 0xC4CEB9FE1A85EC53],
                      dtype=np.uint64)


def trace_id_from_path(path: str | os.PathLike) -> str:
    """Trace id = file name without ``.gz`` and ``.txt`` suffixes."""
    name = Path(path).name
    for suffix in (".gz", ".txt"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
    return name


def find_trace_files(paths: str | os.PathLike | Iterable[str | os.PathLike]) -> list[Path]:
    """Expand files and folders (recursively) into the sorted list of ``*.txt``/``*.txt.gz``.

    Folders yield regular files only; a path named that is neither a folder nor a regular
    file (a FIFO, socket or device, or a link to one: reading it, or hashing it, would block
    or never end) raises, as a missing one does."""
    found: list[Path] = []
    for p in map(Path, path_list(paths)):
        if p.is_dir():
            found.extend(q for q in p.rglob("*") if q.is_file()
                         and (q.name.endswith(".txt") or q.name.endswith(".txt.gz")))
        elif p.is_file():
            found.append(p)
        elif p.exists():
            raise not_regular(p)
        else:
            raise SurveyFormatError("no such file or folder", path=str(p), reason="missing")
    for f in found:  # the name is the trace id and the path the source, kept in the store
        try:
            str(f).encode("utf-8")
        except UnicodeEncodeError:
            raise SurveyFormatError(
                "the path is not valid UTF-8 (the file name becomes the trace id, the path "
                "is kept in the store): rename it",
                path=os.fsencode(f).decode("utf-8", "backslashreplace"),
                reason="file_name") from None
    return sorted(set(found))


# --------------------------------------------------------------------------------------------
# A batch of texts split into lines


@dataclass
class _Batch:
    buf: np.ndarray  # uint8, the texts concatenated, each ending with b"\n", then zero padding
    scan: ScanResult  # lines, their kinds and types, and the per-group line blocks
    file_of_line: np.ndarray  # int64 per line: index into paths
    first_line: np.ndarray  # int64 per file: global index of its first line (+ total at end)
    paths: list[str]
    cut_lines: np.ndarray  # global indices of lines cut off by a damaged compressed stream

    @property
    def starts(self) -> np.ndarray:
        return self.scan.starts

    @property
    def ends(self) -> np.ndarray:
        return self.scan.ends


#: A UTF-8 byte order mark, which some editors write before the first line.
BOM = b"\xef\xbb\xbf"


def _make_batch(texts: Sequence[bytes], paths: Sequence[str],
                notes: Sequence[str | None]) -> _Batch:
    pieces, cut = [], []
    for text, note in zip(texts, notes):
        if text.startswith(BOM):
            text = text[len(BOM):]
        if note and text and not text.endswith(b"\n"):
            # The partial last line of a damaged stream stands as an empty line, reported below.
            text = text[:text.rfind(b"\n") + 1] + b"\n"
            cut.append(len(pieces))
        elif text and not text.endswith(b"\n"):
            text = text + b"\n"
        pieces.append(text)
    n = sum(len(p) for p in pieces)
    # Zero padding after the text lets fixed-width byte windows run past the last line.
    buf = np.frombuffer(b"".join([*pieces, bytes(_TOKEN_WIDTH)]), dtype=np.uint8)
    scan = scan_lines(buf, n, _TYPE_LIST, _GROUP_OF_INDEX, _GROUP_LAYOUTS)
    file_start = np.cumsum([0] + [len(p) for p in pieces])
    first_line = np.searchsorted(scan.starts, file_start)
    file_of_line = np.searchsorted(file_start, scan.starts, side="right") - 1
    cut_lines = first_line[np.asarray(cut, dtype=np.int64) + 1] - 1
    return _Batch(buf, scan, file_of_line, first_line, list(paths), cut_lines)


class _Collector:
    """Bad lines (global line index, reason, message) found during one batch parse."""

    def __init__(self) -> None:
        self.parts: list[tuple[np.ndarray, str, object]] = []

    def add(self, glines: np.ndarray, reason: str, detail: str | np.ndarray) -> None:
        glines = np.asarray(glines, dtype=np.int64)
        if len(glines):
            self.parts.append((glines, reason, detail))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if not self.parts:
            empty = np.empty(0, dtype=object)
            return np.empty(0, dtype=np.int64), empty, empty
        glines = np.concatenate([p[0] for p in self.parts])
        reasons = np.concatenate([np.full(len(p[0]), p[1], dtype=object) for p in self.parts])
        details = np.concatenate([np.full(len(p[0]), p[2], dtype=object) if isinstance(p[2], str)
                                  else np.asarray(p[2], dtype=object) for p in self.parts])
        order = np.argsort(glines, kind="stable")
        return glines[order], reasons[order], details[order]


# --------------------------------------------------------------------------------------------
# Line classification


def _classify_other(b: _Batch, bad: _Collector) -> dict[str, np.ndarray]:
    """Lines whose type token is not a documented type: undocumented ``TYPE_*`` names are
    returned (name -> global line indices) to be skipped; anything else is a bad line."""
    sc = b.scan
    bad.add(np.flatnonzero(sc.kind == NO_TAB), "no_type",
            "expected 'timestamp<TAB>TYPE...' but found no tab")
    bad.add(np.flatnonzero(sc.kind == BAD_TIMESTAMP), "bad_timestamp",
            "timestamp is not an integer of milliseconds")
    bad.add(np.flatnonzero(sc.kind == BAD_TOKEN), "unknown_record",
            "record type is not a TYPE_ name")
    idx = np.flatnonzero(sc.kind == OTHER_TOKEN)
    skipped: dict[str, np.ndarray] = {}
    if not len(idx):
        return skipped
    lens = sc.tok_len[idx]
    tok = _byte_windows(b.buf, _TOKEN_WIDTH)[sc.tok_start[idx]] & _PREFIX_MASKS[lens]
    words = tok.view(np.uint64)  # (n, 6)
    # The length is part of the key: masked windows of "TYPE_X" and "TYPE_X\0" are equal.
    h = (words * _HASH_MULT).sum(axis=1, dtype=np.uint64) + lens.astype(np.uint64) * _HASH_MULT[0]
    inverse, first = _factorize(h)
    if not ((words == words[first[inverse]]).all() and (lens == lens[first[inverse]]).all()):
        # a hash collision: compare exactly instead
        _, first, inverse = np.unique(np.column_stack([tok, lens.astype(np.uint8)]), axis=0,
                                      return_index=True, return_inverse=True)
        inverse = inverse.ravel()
    for u, row in enumerate(first):
        name = tok[row, :lens[row]].tobytes().decode("latin-1")
        sel = idx[inverse == u]
        if _is_type_name(name):
            skipped[name] = sel
        else:
            bad.add(sel, "unknown_record", f"record type {name[:40]!r} is not a TYPE_ name")
    return skipped


def _factorize(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Codes per key and the index of each code's first occurrence (hash-based, O(n))."""
    codes, uniques = pd.factorize(keys)
    first = np.empty(len(uniques), dtype=np.int64)
    first[codes[::-1]] = np.arange(len(codes) - 1, -1, -1)
    return codes, first


def _byte_windows(buf: np.ndarray, width: int) -> np.ndarray:
    """Read-only view whose row i is ``buf[i:i + width]`` (``buf`` ends with ``width`` zeros).

    Fancy-indexing its rows gathers ``width`` bytes per index without an index per byte."""
    return np.lib.stride_tricks.as_strided(buf, shape=(len(buf) - width + 1, width),
                                           strides=(1, 1), writeable=False)


def _is_type_name(name: str) -> bool:
    return (len(name) > 5 and name.startswith("TYPE_")
            and all(c.isascii() and (c.isupper() or c.isdigit() or c == "_") for c in name))


# --------------------------------------------------------------------------------------------
# Parsing one block of lines that share a value layout


def _arrow_options(spec: list[tuple[str, str]]):
    names = ["t_ms"] + [c for c, _ in spec]
    types = {"t_ms": pa.int64(), **{c: _ARROW_KIND[kind] for c, kind in spec}}
    return (
        # One thread: iter_traces overlaps this stage of one batch with the rest of another.
        pacsv.ReadOptions(column_names=names, use_threads=False, block_size=1 << 26),
        pacsv.ParseOptions(delimiter="\t", quote_char=False, double_quote=False,
                           escape_char=False, newlines_in_values=False,
                           ignore_empty_lines=False),
        pacsv.ConvertOptions(column_types=types, strings_can_be_null=False,
                             quoted_strings_can_be_null=False, null_values=[], check_utf8=True),
    )


def _read_block(block: np.ndarray, spec, n_rows: int) -> dict | None:
    """Fast path: pyarrow's CSV parser reads a block of ``timestamp<TAB>values`` lines into
    columns (numpy; arrow for strings), or ``None`` if some line defeats it. Thread-safe."""
    try:
        ro, po, co = _arrow_options(spec)
        table = pacsv.read_csv(pa.BufferReader(pa.py_buffer(block)), read_options=ro,
                               parse_options=po, convert_options=co)
        if table.num_rows != n_rows:
            return None
        return {c: (table.column(c).combine_chunks() if kind == "s"
                    else table.column(c).to_numpy()) for c, kind in [("t_ms", "i"), *spec]}
    except (pa.ArrowInvalid, UnicodeDecodeError, ValueError):
        return None


def _parse_block(sc: ScanResult, g: int, cols: dict | None, bad: _Collector,
                 what: str) -> dict[str, np.ndarray | pa.Array]:
    """Columns of the lines of value-layout group ``g``, bad rows removed, plus ``gline``
    (global line index). Lines the scan parsed come from it; the rest from ``cols``, the fast
    path's result for the group's joined text, or, without it, from a line-by-line re-read."""
    spec, glines, parsed = _GROUP_SPECS[g], sc.group_lines[g], sc.group_parsed[g]
    rest = glines[~parsed]
    keep = np.ones(len(rest), dtype=bool)
    if len(rest) and cols is None:
        names = np.asarray(_TYPE_LIST, dtype=object)[sc.type_idx[rest]]
        cols, keep, reasons, details = _parse_block_slow(sc.group_bytes[g].tobytes(), spec, names)
        for reason in np.unique(reasons[~keep]):
            sel = ~keep & (reasons == reason)
            bad.add(rest[sel], str(reason), details[sel])
    if len(rest) < len(glines):  # merge the scan's rows with the rest, in line order
        merged = {"t_ms": sc.group_t_ms[g]}
        for j, (c, kind) in enumerate(spec):
            values = sc.group_values[g][j]
            if kind == "i":  # integers of at most 15 digits: exact in float64
                values = np.where(parsed, values, 0).astype(np.int64) if len(rest) else \
                    values.astype(np.int64)
            merged[c] = values
        keep_all = np.ones(len(glines), dtype=bool)
        if len(rest):
            for c in merged:
                merged[c][~parsed] = cols[c]
            keep_all[~parsed] = keep
        cols, keep = merged, keep_all
    finite = keep.copy()
    for c, kind in spec:
        if kind == "f":
            finite &= np.isfinite(cols[c])
        elif kind == "i":  # not np.abs: it overflows for the int64 minimum
            finite &= (cols[c] > -_INT_LIMIT) & (cols[c] < _INT_LIMIT)
    refused = glines[finite != keep]
    # the sensor groups hold several record types: each line's own (a walk refused for no
    # rotation vector names its rotation-vector lines)
    named = (np.asarray(_TYPE_LIST, dtype=object)[sc.type_idx[refused]] if g < 2
             else np.full(len(refused), what, dtype=object))
    bad.add(refused, "non_finite", named + ": a value is NaN, infinite or too large")
    cols["gline"] = glines
    return _take(cols, np.flatnonzero(finite)) if not finite.all() else cols


def _drop_time_outliers(blocks: list[dict | None], b: _Batch, bad: _Collector) -> None:
    """Rows far from the median time of their file's records of their type
    (:func:`~survey.trace_format.far_from_median_time`) become ``time_outlier`` bad lines and
    leave ``blocks``."""
    present = [i for i, c in enumerate(blocks) if c is not None and len(c["gline"])]
    if not present:
        return
    n_types = len(_TYPE_LIST)
    far = far_from_median_time(
        np.concatenate([blocks[i]["t_ms"] for i in present]),
        np.concatenate([b.file_of_line[blocks[i]["gline"]] * n_types + blocks[i]["type"]
                        for i in present]),
        len(b.paths) * n_types)
    at = 0
    for i in present:
        cols = blocks[i]
        n = len(cols["gline"])
        mine, at = far[at:at + n], at + n
        if mine.any():
            glines = cols["gline"][mine]
            # a message per row is only needed for the rows a report can show, each file's
            # first MAX_MESSAGES bad lines: a log half on another clock has 10^5-10^6 of them
            detail = np.full(len(glines), "time far from the median time of the walk's rows of "
                                           "its type", dtype=object)
            shown = _first_per_file(glines, b.file_of_line, MAX_MESSAGES)
            detail[shown] = [f"{_TYPE_LIST[k]}: time {int(t)} ms is over "
                             f"{MAX_FROM_MEDIAN_TIME_MS // 3_600_000} h from the median time "
                             "of the walk's rows of this type (a wrong clock or a stray row)"
                             for k, t in zip(cols["type"][mine][shown],
                                             cols["t_ms"][mine][shown])]
            bad.add(glines, "time_outlier", detail)
            blocks[i] = _take(cols, np.flatnonzero(~mine))


def _first_per_file(glines: np.ndarray, file_of_line: np.ndarray, n: int) -> np.ndarray:
    """Indices into ``glines`` (global line numbers) of the first ``n`` lines of each file."""
    files = file_of_line[glines]
    order = np.lexsort((glines, files))
    sorted_files = files[order]
    rank = np.arange(len(order)) - np.searchsorted(sorted_files, sorted_files, side="left")
    return order[rank < n]


def _take(cols: dict, index: np.ndarray) -> dict:
    return {c: (v.take(pa.array(index, type=pa.int64())) if isinstance(v, pa.Array) else v[index])
            for c, v in cols.items()}


def _parse_block_slow(block: bytes, spec, type_names: np.ndarray):
    """Line-by-line fallback: (columns, keep mask, reasons, details) for every line.

    ``type_names`` holds each line's record type (the block's lines lack that field)."""
    raw_lines = block.split(b"\n")[:-1]
    n = len(raw_lines)
    out: dict[str, list] = {"t_ms": [0] * n}
    for c, kind in spec:
        out[c] = [("" if kind == "s" else 0)] * n
    keep = np.ones(n, dtype=bool)
    reasons = np.full(n, "", dtype=object)
    details = np.full(n, "", dtype=object)
    for i, raw in enumerate(raw_lines):
        raw = raw[:-1] if raw.endswith(b"\r") else raw
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            keep[i], reasons[i], details[i] = False, "invalid_utf8", "line is not valid UTF-8"
            continue
        fields = text.split("\t")
        if len(fields) != len(spec) + 1:
            keep[i], reasons[i] = False, "field_count"
            details[i] = f"{type_names[i]} needs {len(spec)} values, got {len(fields) - 1}"
            continue
        out["t_ms"][i] = int(fields[0])
        for (c, kind), value in zip(spec, fields[1:]):
            if kind == "s":
                out[c][i] = value
                continue
            try:
                number = _float(value) if kind == "f" else _int(value)
            except ValueError:
                keep[i], reasons[i] = False, "non_numeric"
                expected = "a number" if kind == "f" else "an integer"
                details[i] = (f"{type_names[i]}: field {c!r} expected {expected}, "
                              f"got {value[:30]!r}")
                break
            # An integer too large for the format is flagged ``non_finite`` by the caller, as
            # on the fast path; clip it so that it fits the int64 column until then.
            out[c][i] = number if kind == "f" or abs(number) < _INT_LIMIT else _INT_LIMIT
    cols: dict[str, np.ndarray | pa.Array] = {"t_ms": np.array(out["t_ms"], dtype=np.int64)}
    for c, kind in spec:
        cols[c] = (pa.array(out[c], type=pa.string()) if kind == "s"
                   else np.array(out[c], dtype=np.float64 if kind == "f" else np.int64))
    return cols, keep, reasons, details


def _int(value: str) -> int:
    """An integer field as pyarrow reads it (also 0x-hex, as two's complement int64)."""
    if _ARROW_DEC_INT.fullmatch(value):
        return int(value)
    m = _ARROW_HEX_INT.fullmatch(value)
    if not m:
        raise ValueError(f"not an integer: {value[:30]!r}")
    number = int(m.group(1), 16)
    return number - 2**64 if number >= 2**63 else number


def _float(value: str) -> float:
    """A float field as pyarrow reads it (also ``nan(...)``)."""
    if _ARROW_NAN.fullmatch(value):
        return float("nan")
    if _PYTHON_ONLY_FLOAT.search(value):
        raise ValueError(f"not a number: {value[:30]!r}")
    return float(value)


# --------------------------------------------------------------------------------------------
# Building the per-trace tables from parsed blocks. Every builder sorts rows by file first and
# returns (rows per file as index ranges, arrays), so that tables are split with slices.


def normalize_bssids(raw: pa.Array) -> tuple[pa.Array, np.ndarray]:
    """Lower-case colon-separated MACs and a validity mask.

    Canonical 17-character entries (``AA:BB:..`` in any case) are checked and lower-cased as a
    fixed-width byte array; anything else (``aa-bb-..``, bare 12 hex digits, blanks, garbage)
    goes through the general path.
    """
    raw = raw.cast(pa.string())
    n = len(raw)
    offsets = np.frombuffer(raw.buffers()[1], dtype=np.int32, count=n + 1,
                            offset=raw.offset * 4) if n else np.zeros(1, np.int32)
    data = np.frombuffer(raw.buffers()[2], dtype=np.uint8) if n and raw.buffers()[2] \
        else np.zeros(0, np.uint8)
    rows, ok = canonical_macs(offsets, data)
    out = pa.StringArray.from_buffers(n, pa.py_buffer((np.arange(n + 1) * 17).astype(np.int32)),
                                      pa.py_buffer(rows))
    valid = ok.copy()
    other = np.flatnonzero(~ok)
    if len(other):
        rest = pc.replace_substring(pc.utf8_lower(pc.utf8_trim_whitespace(
            raw.take(pa.array(other)))), "-", ":")
        bare = pc.match_substring_regex(rest, r"^[0-9a-f]{12}$")
        rest = pc.if_else(bare, pc.replace_substring_regex(
            rest, r"^(..)(..)(..)(..)(..)(..)$", r"\1:\2:\3:\4:\5:\6"), rest)
        valid[other] = pc.match_substring_regex(
            rest, r"^[0-9a-f]{2}(:[0-9a-f]{2}){5}$").to_numpy(zero_copy_only=False)
        merged = np.asarray(out.to_numpy(zero_copy_only=False), dtype=object)
        merged[other] = np.asarray(rest.to_numpy(zero_copy_only=False), dtype=object)
        out = pa.array(merged, type=pa.string())
    return out, valid


def _lex_order(*keys: np.ndarray) -> np.ndarray:
    """Stable order of rows by integer ``keys`` (the first most significant), as
    ``np.lexsort(keys[::-1])``; the keys are packed into one int64 when their ranges allow."""
    lows = [int(k.min()) if len(k) else 0 for k in keys]
    spans = [int(k.max()) - lo + 1 if len(k) else 1 for k, lo in zip(keys, lows)]
    if np.prod([float(x) for x in spans]) >= 2.0**62:
        return np.lexsort(keys[::-1])
    packed = np.zeros(len(keys[0]), dtype=np.int64)
    for k, lo, span in zip(keys, lows, spans):
        packed *= span
        packed += k.astype(np.int64, copy=False) - lo
    return np.argsort(packed, kind="stable")


def _file_ranges(file_sorted: np.ndarray, n_files: int) -> np.ndarray:
    return np.searchsorted(file_sorted, np.arange(n_files + 1))


def _str_array(values: pa.Array) -> pd.api.extensions.ExtensionArray:
    return pd.array(values, dtype="str")


def _split(frame: pd.DataFrame, ranges: np.ndarray) -> list[pd.DataFrame]:
    """Row ranges of ``frame`` (sorted by file) as one frame per file, index from 0."""
    return [frame.iloc[ranges[i]:ranges[i + 1]].reset_index(drop=True)
            for i in range(len(ranges) - 1)]


#: Why a row's RSSI is refused (:func:`localize.bundle.rssi_reading`).
RSSI_REFUSED = (f"rssi outside [{RSSI_RANGE_DBM[0]:g}, {RSSI_RANGE_DBM[1]:g}) dBm (0: a "
                "driver's 'no reading')")


def wifi_row_checks(cols: dict) -> tuple[pa.Array, list[tuple[str, str, np.ndarray]]]:
    """The Wi-Fi rows' BSSIDs normalized (:func:`normalize_bssids`) and the rows refused, as
    ``(reason, detail, rows)`` with disjoint masks (n,), in order: a BSSID that is no MAC
    address, RSSI outside :data:`RSSI_RANGE_DBM`, a frequency that is not in MHz, a last-seen
    time more than :data:`MAX_WIFI_SEEN_AFTER_SCAN_MS` after the scan. ``cols``: ``bssid``
    (pyarrow strings) and ``t_ms`` (scan time), ``last_seen_ms``, ``rssi_dbm``, ``freq_mhz``
    (numbers, n,)."""
    bssid, valid = normalize_bssids(cols["bssid"])
    rssi_ok = rssi_reading(cols["rssi_dbm"])
    freq_ok = (cols["freq_mhz"] >= 1) & (cols["freq_mhz"] <= 100_000)
    seen_ok = cols["last_seen_ms"] <= cols["t_ms"] + MAX_WIFI_SEEN_AFTER_SCAN_MS
    return bssid, [
        ("bad_bssid", "bssid is not a MAC address", ~valid),
        ("out_of_range", RSSI_REFUSED, valid & ~rssi_ok),
        ("out_of_range", "frequency is not in MHz", valid & rssi_ok & ~freq_ok),
        ("out_of_range", f"last-seen time more than {MAX_WIFI_SEEN_AFTER_SCAN_MS} ms after "
                         "the scan", valid & rssi_ok & freq_ok & ~seen_ok)]


def beacon_row_checks(cols: dict) -> list[tuple[str, str, np.ndarray]]:
    """The BLE rows refused, as ``(reason, detail, rows)`` with disjoint masks (n,), in
    order: RSSI outside :data:`RSSI_RANGE_DBM`, a major or minor outside [0, 65535] or an
    absurd TX power. ``cols``: ``rssi_dbm``, ``major``, ``minor``, ``tx_power_dbm`` (numbers,
    n,)."""
    ok = rssi_reading(cols["rssi_dbm"])
    ok_id = ((cols["major"] >= 0) & (cols["major"] < 2**16) & (cols["minor"] >= 0)
             & (cols["minor"] < 2**16) & (np.abs(cols["tx_power_dbm"]) < 2**15))
    return [("out_of_range", RSSI_REFUSED, ~ok),
            ("out_of_range", "major/minor outside [0, 65535] or absurd tx power", ok & ~ok_id)]


def wifi_table(files: np.ndarray, cols: dict
               ) -> tuple[pd.DataFrame, np.ndarray, np.ndarray, np.ndarray]:
    """Checked Wi-Fi rows as the store's table (:data:`WIFI_COLUMNS`), sorted by file, scan
    time and BSSID; a scan that lists a BSSID more than once keeps the freshest row (latest
    last-seen time), then the strongest RSSI, then the first in file order.

    ``files`` (n,): each row's file; ``cols``: ``t_ms`` (scan time), ``last_seen_ms``,
    ``rssi_dbm``, ``freq_mhz`` (integer arrays, n,), ``ssid`` and ``bssid`` (pyarrow string
    arrays, BSSIDs normalized by :func:`normalize_bssids`), rows in file order. Returns the
    table, each of its rows' file, the files of the rows dropped as repeated and those of the
    rows whose age was taken as 0, their last-seen times on another clock
    (:data:`MAX_WIFI_AGE_MS`)."""
    enc = pc.dictionary_encode(cols["bssid"])
    dictionary = enc.dictionary.to_numpy(zero_copy_only=False)
    rank = np.argsort(np.argsort(dictionary, kind="stable"))
    bcode = rank[enc.indices.to_numpy(zero_copy_only=False)] if len(dictionary) else \
        np.zeros(0, dtype=np.int64)
    # the sort is stable and rows are in file order: "first in file order" is first here
    order = _lex_order(files, cols["t_ms"], bcode)
    files, scan, bc = files[order], cols["t_ms"][order], bcode[order]
    dup = best_of_runs(files, scan, bc, cols["last_seen_ms"][order], cols["rssi_dbm"][order])
    dropped = files[dup]
    if dup.any():
        order, files, scan = order[~dup], files[~dup], scan[~dup]
    take = pa.array(order, type=pa.int64())
    seen = cols["last_seen_ms"][order]
    age = scan - seen
    other_clock = age > MAX_WIFI_AGE_MS
    age[other_clock] = 0
    frame = pd.DataFrame({
        "scan_t_ms": scan, "ssid": _str_array(cols["ssid"].take(take)),
        "bssid": _str_array(cols["bssid"].take(take)),
        "rssi_dbm": cols["rssi_dbm"][order].astype(np.int16),
        "freq_mhz": cols["freq_mhz"][order].astype(np.int32),
        "last_seen_ms": seen, "age_ms": age})
    return frame, files, dropped, files[other_clock]


def beacon_table(files: np.ndarray, cols: dict) -> tuple[pd.DataFrame, np.ndarray]:
    """Checked BLE rows as the store's table (:data:`BLE_COLUMNS`), sorted by file and time
    (rows of one time keep their file order); a beacon's key is ``uuid:major:minor`` with
    the UUID lower-cased.

    ``files`` (n,): each row's file; ``cols``: ``t_ms``, ``major``, ``minor``,
    ``tx_power_dbm``, ``rssi_dbm``, ``last_seen_ms`` (integer arrays, n,), ``distance_m``
    (float, m) and ``uuid``, ``mac`` (pyarrow string arrays), rows in file order. Returns the
    table and each of its rows' file."""
    order = _lex_order(files, cols["t_ms"])  # rows are in line order; the sort is stable
    files = files[order]
    take = pa.array(order, type=pa.int64())
    uuid = pc.utf8_lower(pc.utf8_trim_whitespace(cols["uuid"].take(take)))
    mac = pc.utf8_lower(pc.utf8_trim_whitespace(cols["mac"].take(take)))
    major, minor = cols["major"][order], cols["minor"][order]
    key = pc.binary_join_element_wise(uuid, pa.array(major.astype(str)),
                                      pa.array(minor.astype(str)), ":")
    frame = pd.DataFrame({
        "t_ms": cols["t_ms"][order], "uuid": _str_array(uuid),
        "major": major.astype(np.int32), "minor": minor.astype(np.int32),
        "key": _str_array(key), "tx_power_dbm": cols["tx_power_dbm"][order].astype(np.int16),
        "rssi_dbm": cols["rssi_dbm"][order].astype(np.int16),
        "distance_m": cols["distance_m"][order], "mac": _str_array(mac),
        "last_seen_ms": cols["last_seen_ms"][order]})
    return frame, files


def drop_repeats(frame: pd.DataFrame, files: np.ndarray
                 ) -> tuple[pd.DataFrame, np.ndarray, np.ndarray]:
    """``frame`` (rows sorted by file, then by ``t_ms``, stable) without the rows that
    repeat an earlier row of the same file in every column; returns it, its rows' files and
    the files of the rows dropped.

    Only rows that share their file and time with a neighbour can repeat one (equal rows
    are next to each other in that order), so the full comparison runs on those alone:
    none in the ILC traces."""
    none = files[:0]
    t = frame["t_ms"].to_numpy()
    same = (files[1:] == files[:-1]) & (t[1:] == t[:-1])
    if not same.any():
        return frame, files, none
    maybe = np.flatnonzero(np.append(same, False) | np.insert(same, 0, False))
    dup = np.zeros(len(frame), bool)
    dup[maybe] = frame.iloc[maybe].assign(_file=files[maybe]).duplicated().to_numpy()
    if not dup.any():
        return frame, files, none
    return frame[~dup], files[~dup], files[dup]


class _Tables:
    """Per-file tables of one batch, plus per-file record and drop counts."""

    def __init__(self, b: _Batch) -> None:
        self.b = b
        self.n_files = len(b.paths)
        self.records = np.zeros((self.n_files, len(_TYPE_LIST)), dtype=np.int64)
        self.dropped: dict[str, np.ndarray] = {}

    def count(self, cols: dict) -> np.ndarray:
        """Count kept records per file and type; returns the file of every row."""
        f = self.b.file_of_line[cols["gline"]]
        n_types = self.records.shape[1]
        self.records += np.bincount(f * n_types + cols["type"],
                                    minlength=self.records.size).reshape(self.records.shape)
        return f

    def drop(self, name: str, files: np.ndarray) -> None:
        """Count rows dropped under ``name`` per file (``files``: each row's file index;
        nothing is counted when it is empty)."""
        if len(files):
            self.dropped[name] = np.bincount(files, minlength=self.n_files)

    def sensors(self, blocks: list[dict | None], bad: _Collector) -> list[pd.DataFrame]:
        parts = []
        for cols in blocks:
            if cols is None:
                continue
            acc_ok = np.abs(cols["accuracy"]) <= 127
            bad.add(cols["gline"][~acc_ok], "out_of_range", "accuracy must be a small integer")
            # Values are stored as float32: a finite float64 beyond its range would be
            # infinite. The largest |value| of a row (NaN when one is NaN, which fails too).
            mag = np.abs(np.column_stack([cols[c] for c in ("x", "y", "z", "bx", "by", "bz")
                                          if c in cols])).max(axis=1)
            ok = acc_ok & (mag < _FLOAT32_LIMIT)
            bad.add(cols["gline"][acc_ok & ~ok], "non_finite",
                    "sensor record: a value is too large for float32")
            implausible = ok & (mag > SENSOR_LIMITS[cols["type"]])
            for t in np.unique(cols["type"][implausible]):
                bad.add(cols["gline"][implausible & (cols["type"] == t)], "out_of_range",
                        f"{_TYPE_LIST[t]}: a value beyond +-{SENSOR_LIMITS[t]:g} "
                        f"{_SENSOR_UNIT[t]}, impossible for a phone's sensor")
            ok &= ~implausible
            if not ok.all():
                cols = _take(cols, np.flatnonzero(ok))
            if "bx" not in cols:
                for c in ("bx", "by", "bz"):
                    cols[c] = np.full(len(cols["t_ms"]), np.nan)
            parts.append(cols)
        if not parts:
            return [self._empty_sensors() for _ in range(self.n_files)]
        cat = {c: np.concatenate([p[c] for p in parts])
               for c in ("t_ms", "x", "y", "z", "bx", "by", "bz", "accuracy", "gline", "type")}
        files = self.count(cat)
        code = _STREAM_CODE_OF_TYPE[cat["type"]]
        # Equal (file, stream, time) rows come from one block, in line order: a stable sort
        # keeps the first line first.
        order = _lex_order(files, code, cat["t_ms"])
        files, code, t = files[order], code[order], cat["t_ms"][order]
        dup = np.zeros(len(order), dtype=bool)
        dup[1:] = (files[1:] == files[:-1]) & (code[1:] == code[:-1]) & (t[1:] == t[:-1])
        if dup.any():
            self.drop("duplicate_timestamp", files[dup])
            order, files, code, t = order[~dup], files[~dup], code[~dup], t[~dup]
        frame = pd.DataFrame({
            "stream": pd.Categorical.from_codes(code, categories=list(STREAM_NAMES)),
            "t_ms": t,
            **{c: cat[c][order].astype(np.float32) for c in ("x", "y", "z", "bx", "by", "bz")},
            "accuracy": cat["accuracy"][order].astype(np.int8)})
        return _split(frame, _file_ranges(files, self.n_files))

    @staticmethod
    def _empty_sensors() -> pd.DataFrame:
        table = empty_table(SENSOR_COLUMNS, SENSOR_DTYPES)
        table["stream"] = stream_category([])
        return table

    def wifi(self, cols: dict | None, bad: _Collector) -> list[pd.DataFrame]:
        if cols is None:
            return [empty_table(WIFI_COLUMNS, WIFI_DTYPES) for _ in range(self.n_files)]
        cols["bssid"], refused = wifi_row_checks(cols)
        cols = _refused_out(cols, refused, bad, "TYPE_WIFI")
        frame, files, dropped, other_clock = wifi_table(self.count(cols), cols)
        self.drop("duplicate_bssid_in_scan", dropped)
        self.drop("wifi_last_seen_other_clock", other_clock)
        return _split(frame, _file_ranges(files, self.n_files))

    def ble(self, cols: dict | None, bad: _Collector) -> list[pd.DataFrame]:
        if cols is None:
            return [empty_table(BLE_COLUMNS, BLE_DTYPES) for _ in range(self.n_files)]
        cols = _refused_out(cols, beacon_row_checks(cols), bad, "TYPE_BEACON")
        frame, files = beacon_table(self.count(cols), cols)
        frame, files, dropped = drop_repeats(frame, files)
        self.drop("duplicate_beacon", dropped)
        return _split(frame, _file_ranges(files, self.n_files))

    def waypoints(self, cols: dict | None, bad: _Collector) -> list[pd.DataFrame]:
        if cols is None:
            return [empty_table(WAYPOINT_COLUMNS, WAYPOINT_DTYPES) for _ in range(self.n_files)]
        ok = np.maximum(np.abs(cols["x_m"]), np.abs(cols["y_m"])) <= WAYPOINT_LIMIT_M
        if not ok.all():
            bad.add(cols["gline"][~ok], "out_of_range",
                    f"TYPE_WAYPOINT: a coordinate beyond +-{WAYPOINT_LIMIT_M:g} m")
            cols = _take(cols, np.flatnonzero(ok))
        files = self.count(cols)
        order = _lex_order(files, cols["t_ms"])  # rows are in line order; the sort is stable
        frame = pd.DataFrame({"t_ms": cols["t_ms"][order], "x_m": cols["x_m"][order],
                              "y_m": cols["y_m"][order]})
        frame, files, dropped = drop_repeats(frame, files[order])
        self.drop("duplicate_waypoint", dropped)
        return _split(frame, _file_ranges(files, self.n_files))


def _refused_out(cols: dict, refused: list[tuple[str, str, np.ndarray]], bad: _Collector,
                 record: str) -> dict:
    """``cols`` without the rows a row check refused (``(reason, detail, rows)`` each), those
    counted in ``bad`` as ``record`` lines (``TYPE_WIFI``)."""
    for reason, detail, rows in refused:
        bad.add(cols["gline"][rows], reason, f"{record}: {detail}")
    keep = ~np.logical_or.reduce([rows for _, _, rows in refused])
    return cols if keep.all() else _take(cols, np.flatnonzero(keep))


# --------------------------------------------------------------------------------------------
# The whole parse


def parse_traces(texts: Sequence[bytes], paths: Sequence[str], *, strict: bool = False,
                 notes: Sequence[str | None] | None = None) -> list[Trace]:
    """Parse several trace texts (already decompressed) in one batch.

    Parameters
    ----------
    texts : sequence of bytes
        One text per trace.
    paths : sequence of str
        The file each text came from (for trace ids and messages).
    strict : bool
        Raise :class:`SurveyFormatError` at the first bad line (of the first trace with one).
        In both modes a text whose header gives a key twice with different values (two
        traces joined into one file) raises (reason ``header_conflict``).
    notes : sequence of str or None, optional
        Per text, a description of a damaged compressed stream whose readable prefix the text
        is; its last line, if it lacks a newline, is then reported as a bad ``truncated`` line.

    Returns
    -------
    list of Trace
        One per text, in order.
    """
    notes = list(notes) if notes is not None else [None] * len(texts)
    traces = _assemble(_prepare(texts, paths, notes), strict)
    for t in traces:
        if isinstance(t, ReadFailure):
            raise t.error
    return traces


def _prepare(texts: Sequence[bytes], paths: Sequence[str], notes: Sequence[str | None]
             ) -> tuple[_Batch, list[str | None], dict[int, dict | None]]:
    """First stage of :func:`parse_traces`, which holds the GIL very little (compiled scan,
    pyarrow): the batch, and the fast-path columns of each group's unparsed lines."""
    b = _make_batch(texts, paths, notes)
    sc = b.scan
    fast = {g: _read_block(sc.group_bytes[g], _GROUP_SPECS[g], int((~sc.group_parsed[g]).sum()))
            for g in range(len(_GROUP_SPECS)) if len(sc.group_bytes[g])}
    return b, list(notes), fast


def _assemble(prepared: tuple[_Batch, list[str | None], dict[int, dict | None]],
              strict: bool) -> list[Trace | ReadFailure]:
    """Second stage of :func:`parse_traces`: checks, tables and reports per trace; a
    :class:`ReadFailure` for a text refused whole (lenient mode; strict raises)."""
    b, notes, fast = prepared
    n_files = len(b.paths)
    bad = _Collector()
    kind = b.scan.kind
    blank, header = kind == BLANK, kind == HEADER
    blank[b.cut_lines] = False
    for f, line in zip(np.searchsorted(b.first_line, b.cut_lines, side="right") - 1,
                       b.cut_lines):
        bad.add(np.array([line]), "truncated", f"last line cut off ({notes[f]})")

    skipped = _classify_other(b, bad)
    sc = b.scan
    blocks: list[dict | None] = [None] * len(_GROUP_SPECS)
    for g in range(len(_GROUP_SPECS)):
        sel = sc.group_lines[g]
        if not len(sel):
            continue
        what = "sensor record" if g < 2 else _TYPE_LIST[sc.type_idx[sel[0]]]
        cols = _parse_block(sc, g, fast.get(g), bad, what)
        cols["type"] = sc.type_idx[cols["gline"]].astype(np.int32)
        blocks[g] = cols

    _drop_time_outliers(blocks, b, bad)
    tables = _Tables(b)
    sensors = tables.sensors(blocks[:2], bad)
    wifi = tables.wifi(blocks[2], bad)
    ble = tables.ble(blocks[3], bad)
    waypoints = tables.waypoints(blocks[4], bad)

    heads: list[TraceHeader | SurveyFormatError] = []
    for f in range(n_files):
        hdr = np.flatnonzero(header[b.first_line[f]:b.first_line[f + 1]])  # 0-based lines
        at = hdr + b.first_line[f]
        lines = [b.buf[s:e].tobytes() for s, e in zip(b.starts[at], b.ends[at])]
        try:  # a key repeated with another value: two traces joined, refused in both modes
            heads.append(parse_header(lines, path=b.paths[f], line_numbers=hdr + 1))
        except SurveyFormatError as err:
            heads.append(err)

    glines, reasons, details = bad.arrays()
    bad_file = b.file_of_line[glines]
    if strict:  # the first problem in file order: a bad line or a conflicting header line
        first = [(f, h.line, h) for f, h in enumerate(heads) if isinstance(h, SurveyFormatError)]
        if len(glines):
            i = int(np.argmin(bad_file * (len(b.starts) + 1) + glines))
            f = int(bad_file[i])
            line = int(glines[i] - b.first_line[f] + 1)
            first.append((f, line, SurveyFormatError(str(details[i]), path=b.paths[f],
                                                     line=line, reason=str(reasons[i]))))
        if first:
            raise min(first, key=lambda x: x[:2])[2]

    per_file = lambda mask: np.bincount(b.file_of_line[mask], minlength=n_files)  # noqa: E731
    lines_total = np.diff(b.first_line)
    n_header, n_blank = per_file(header), per_file(blank)
    skipped_per_file = {k: np.bincount(b.file_of_line[v], minlength=n_files)
                        for k, v in sorted(skipped.items())}
    bad_bounds = _file_ranges(bad_file, n_files)  # glines sorted => files sorted

    traces: list[Trace | ReadFailure] = []
    for f in range(n_files):
        head = heads[f]
        if isinstance(head, SurveyFormatError):
            traces.append(ReadFailure(b.paths[f], head))
            continue
        report = ParseReport(path=b.paths[f], lines_total=int(lines_total[f]),
                             header_lines=int(n_header[f]), blank_lines=int(n_blank[f]))
        report.records = {_TYPE_LIST[t]: int(c) for t, c in enumerate(tables.records[f]) if c}
        report.skipped = {k: int(v[f]) for k, v in skipped_per_file.items() if v[f]}
        report.dropped = {k: int(v[f]) for k, v in tables.dropped.items() if v[f]}
        a, z = bad_bounds[f], bad_bounds[f + 1]
        report.bad = dict(Counter(reasons[a:z].tolist()))
        m = min(z, a + MAX_MESSAGES)  # this file's bad lines only
        report.messages = [f"{b.paths[f]}:{g - b.first_line[f] + 1}: {d}"
                           for g, d in zip(glines[a:m], details[a:m])]
        if notes[f]:
            report.messages.insert(0, f"{b.paths[f]}: {notes[f]}; kept the readable part")
        traces.append(Trace(trace_id=trace_id_from_path(b.paths[f]), header=head,
                            sensors=sensors[f], wifi=wifi[f], ble=ble[f],
                            waypoints=waypoints[f], report=report))
    return traces


def parse_trace_bytes(data: bytes, *, path: str = "<input>", strict: bool = False,
                      note: str | None = None) -> Trace:
    """Parse one trace text (already decompressed); see :func:`parse_traces`."""
    return parse_traces([data], [path], strict=strict, notes=[note])[0]


# --------------------------------------------------------------------------------------------
# Public entry points


def read_trace(path: str | os.PathLike, *, strict: bool = False,
               max_bytes: int = MAX_TRACE_BYTES) -> Trace:
    """Read one survey trace (``.txt`` or ``.txt.gz``; gzip is detected by its magic bytes).

    Parameters
    ----------
    path : path-like
        The trace file.
    strict : bool
        Raise :class:`SurveyFormatError` for the first bad line (or a damaged gzip stream)
        instead of skipping and counting it.
    max_bytes : int
        Refuse a file larger than this on disk, or whose text is (bytes, after
        decompression).

    Returns
    -------
    Trace
        Header, the sensor / Wi-Fi / BLE / waypoint tables sorted by time, and a
        :class:`ParseReport` that accounts for every line.

    Raises
    ------
    SurveyFormatError
        Unreadable file (or not a regular file: a folder, a FIFO), over-size input, a damaged
        gzip stream, a header giving one key two different values (two traces joined into one
        file), no sensor sample, waypoint or scan at all (empty, or not a trace file: reason
        ``"empty"``), or (strict) the first malformed line, naming ``file:line`` and the
        reason.
    """
    data, note = read_trace_bytes(path, strict=strict, max_bytes=max_bytes)
    trace = parse_trace_bytes(data, path=str(path), strict=strict, note=note)
    if trace.is_empty:
        raise _not_a_trace(trace)
    return trace


@dataclass
class ReadFailure:
    """A file that could not be read at all (lenient :func:`iter_traces` yields these)."""

    path: str
    error: SurveyFormatError


def iter_traces(paths: str | os.PathLike | Iterable[str | os.PathLike], *,
                strict: bool = False,
                batch_bytes: int = BATCH_BYTES,
                max_bytes: int = MAX_TRACE_BYTES) -> Iterator[Trace | ReadFailure]:
    """Read traces in batches of about ``batch_bytes`` of text, yielding them in path order.

    In lenient mode a file that cannot be read at all (I/O error, not a regular file,
    over-size, damaged gzip stream, conflicting header: two traces joined, no record at all:
    empty or not a trace file) is yielded as a :class:`ReadFailure` and reading goes on; in
    strict mode its error is raised.
    """
    for item in _read_batched(path_list(paths), strict=strict, batch_bytes=batch_bytes,
                              max_bytes=max_bytes):
        if isinstance(item, Trace) and item.is_empty:
            if strict:
                raise _not_a_trace(item)
            item = ReadFailure(item.report.path, _not_a_trace(item))
        yield item


def _not_a_trace(trace: Trace) -> SurveyFormatError:
    """The error for a file read without any record (see :attr:`Trace.is_empty`)."""
    return SurveyFormatError(trace.empty_reason(), path=trace.report.path, reason="empty")


def _read_batched(paths: Iterable[str | os.PathLike], *, strict: bool, batch_bytes: int,
                  max_bytes: int) -> Iterator[Trace | ReadFailure]:
    """:func:`iter_traces` without its refusal of files without a record."""
    batches = _batches(paths, strict=strict, batch_bytes=batch_bytes, max_bytes=max_bytes)
    with ThreadPoolExecutor(max_workers=1) as stage:
        pending: Future | None = None  # the batch being prepared
        while True:
            try:
                item = next(batches)
            except StopIteration:
                break
            except SurveyFormatError:  # strict: a file that cannot be read; earlier files first
                if pending is not None:
                    yield from _assemble(pending.result(), strict)
                raise
            if isinstance(item, ReadFailure):
                if pending is not None:
                    yield from _assemble(pending.result(), strict)
                    pending = None
                yield item
                continue
            ready, pending = pending, stage.submit(_prepare, *item)
            if ready is not None:
                yield from _assemble(ready.result(), strict)
        if pending is not None:
            yield from _assemble(pending.result(), strict)


def _batches(paths: Iterable[str | os.PathLike], *, strict: bool, batch_bytes: int,
             max_bytes: int) -> Iterator[tuple[list[bytes], list[str], list[str | None]]
                                         | ReadFailure]:
    """Texts (with paths and notes) grouped into batches of about ``batch_bytes``, in path
    order, and :class:`ReadFailure` for unreadable files (lenient mode)."""
    texts: list[bytes] = []
    names: list[str] = []
    notes: list[str | None] = []
    size = 0
    for p, read in _read_ahead(paths, strict=strict, max_bytes=max_bytes,
                               ahead_bytes=batch_bytes // 2):
        try:
            data, note = read.result()
        except SurveyFormatError as err:
            if strict:
                raise
            if texts:
                yield texts, names, notes
            texts, names, notes, size = [], [], [], 0
            yield ReadFailure(str(p), err)
            continue
        texts.append(data)
        names.append(str(p))
        notes.append(note)
        size += len(data)
        if size >= batch_bytes:
            yield texts, names, notes
            texts, names, notes, size = [], [], [], 0
    if texts:
        yield texts, names, notes


def _read_ahead(paths: Iterable[str | os.PathLike], *, strict: bool, max_bytes: int,
                ahead_bytes: int) -> Iterator[tuple[str | os.PathLike, Future]]:
    """(path, future of :func:`read_trace_bytes`) in path order, read in a background thread
    (gunzip releases the GIL, so it overlaps parsing) up to ``ahead_bytes`` of files (on
    disk) ahead of the consumer."""
    with ThreadPoolExecutor(max_workers=1) as pool:
        window: deque[tuple[str | os.PathLike, Future, int]] = deque()
        pending = 0
        for p in paths:
            try:
                size = os.stat(p).st_size
            except OSError:
                size = 0  # read_trace_bytes reports it
            window.append((p, pool.submit(read_trace_bytes, p, strict=strict,
                                          max_bytes=max_bytes), size))
            pending += size
            while len(window) > 1 and pending > ahead_bytes:
                q, read, size = window.popleft()
                pending -= size
                yield q, read
        for q, read, _ in window:
            yield q, read


__all__ = ["read_trace", "parse_trace_bytes", "parse_traces", "iter_traces", "ReadFailure",
           "find_trace_files", "trace_id_from_path", "MAX_TRACE_BYTES", "BATCH_BYTES"]
