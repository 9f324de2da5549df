"""Fuzzing the survey parsers: seed inputs, byte mutators, invariant checks, a seeded runner.

Used by ``tests/test_fuzz_parsers.py`` (a bounded, seeded run in the normal suite, plus a replay
of ``tests/data/corrupt/``) and by ``benchmarks/fuzz_parsers.py`` (the long run).

Seeds are real-format traces: windows of the simulated sample in ``data/sample_site`` (header
plus a run of consecutive lines) and small traces from ``tests/factories.py`` written with
``survey.trace_writer.write_trace``; walk-line seeds are a small plan and its sensor CSVs.
Mutators damage bytes (bit flips, truncation, inserted garbage, deleted or duplicated ranges,
invalid UTF-8, swapped tabs/newlines/CRs, huge numbers, NaN/inf tokens) or the gzip container
(header, deflate body, CRC, length trailer, concatenated or trailing members).

Every check returns a list of problems, each ``"signature: detail"``; an empty list is a pass.
What is checked (see ``docs/trace_format.md`` and ``../shared/RELIABILITY.md`` item 1):

- strict mode raises nothing but :class:`SurveyFormatError`, and raises exactly when lenient
  mode finds a bad line or a damaged gzip stream, with the same ``file:line: reason`` text as
  lenient's first message;
- lenient mode always returns (but refuses a gzip stream damaged inside, or a text whose
  header names two walks, ``header_conflict``, as strict mode does, with the same text:
  ``survey/trace_bytes.py``, ``survey/trace_header.py``); every line is counted once (``accounted_lines() ==
  lines_total``, and ``lines_total`` is the number of lines of the text); the tables have the
  documented columns and dtypes, finite sensor values, valid ranges, and are sorted by time
  within each stream; row counts agree with the per-type record counts;
- a text parsed in a batch with other texts gives exactly what it gives alone;
- no ``RuntimeWarning`` (numpy's signal of an overflowing or invalid cast) is emitted;
- the walk-line reader raises nothing but :class:`SurveyFormatError` and, when it returns, its
  traces keep the same table invariants.
"""

from __future__ import annotations

import copy
import gzip
import hashlib
import itertools
import json
import random
import re
import shutil
import struct
import time
import warnings
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from localize.bundle import RSSI_RANGE_DBM
from survey.errors import SurveyFormatError
from survey.sim.site import ensure_sample_site
from survey.trace_format import (
    BLE_COLUMNS,
    BLE_DTYPES,
    DOCUMENTED_TYPES,
    SENSOR_COLUMNS,
    SENSOR_DTYPES,
    SENSOR_STREAMS,
    STREAM_NAMES,
    WAYPOINT_COLUMNS,
    WAYPOINT_DTYPES,
    WIFI_COLUMNS,
    WIFI_DTYPES,
    Trace,
    empty_table,
    stream_category,
)
from survey.trace_reader import iter_traces, parse_trace_bytes, parse_traces, read_trace
from survey.trace_writer import write_trace
from survey.walkline import is_walk_plan, read_walk_plan

REPO = Path(__file__).resolve().parents[1]
SAMPLE_TRACES = sorted(ensure_sample_site(REPO / "data" / "sample_site")
                       .glob("*/path_data_files/*.txt.gz"))
CORRUPT_DIR = REPO / "tests" / "data" / "corrupt"

BAD_REASONS = {"no_type", "bad_timestamp", "unknown_record", "field_count", "non_numeric",
               "non_finite", "invalid_utf8", "bad_bssid", "out_of_range", "truncated",
               "time_outlier"}
_TYPE_NAME = re.compile(r"TYPE_[A-Z0-9_]+")
_MAC = re.compile(r"[0-9a-f]{2}(:[0-9a-f]{2}){5}")
_UNCAL = [STREAM_NAMES.index(v) for k, v in SENSOR_STREAMS.items()
          if k.endswith("_UNCALIBRATED")]


# ============================================================================================
# Seeds


def sample_texts(limit: int | None = None) -> list[bytes]:
    """Decompressed texts of the committed simulated sample (``limit`` files)."""
    return [gzip.decompress(p.read_bytes()) for p in SAMPLE_TRACES[:limit]]


def damaged_sample_gzip(path: Path) -> Path:
    """Write a damaged gzip trace to ``path``: the first 3,259 bytes of a sample trace's gzip
    stream with byte 464 inverted, so that inflating stops after a short prefix ("invalid
    distance too far back"; the file is now refused whole, as its prefix cannot be trusted).
    It replays the saved input that once leaked a damaged file's messages into the next file
    of a batch; it is generated from the simulated sample,
    never stored, because a stored one would be a trace in the ILC layout."""
    data = bytearray(gzip.compress(sample_texts(1)[0], compresslevel=6, mtime=0)[:3259])
    data[464] ^= 0xFF
    path.write_bytes(bytes(data))
    return path


def sample_window(text: bytes, rng: random.Random, max_lines: int = 300) -> bytes:
    """Header lines plus a random run of consecutive lines of a real-format trace."""
    lines = text.split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    head = [ln for ln in lines[:20] if ln.startswith(b"#")]
    n = rng.randint(1, max_lines)
    a = rng.randrange(max(1, len(lines) - n))
    body = lines[a:a + n]
    if rng.random() < 0.3:
        body.append(lines[-1])  # the endTime line
    return b"\n".join(head + body) + b"\n"


def factory_seeds(folder: Path, count: int = 4) -> list[tuple[bytes, bytes]]:
    """(text, gzip bytes) of small factory traces written with ``write_trace``."""
    from factories import small_trace

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for i in range(count):
        trace = small_trace(n=20 + 15 * i, seed=i, trace_id=f"seed{i}")
        extra = ["1600000000123\tTYPE_BLUE\t\t16:E5:41:F6:CC:67\t-95",
                 "1600000000124\tTYPE_BLU4\t25000\t11257\t-95"][: i % 3]
        txt = write_trace(folder / f"seed{i}.txt", trace, extra_lines=extra).read_bytes()
        gz = write_trace(folder / f"seed{i}.txt.gz", trace, extra_lines=extra).read_bytes()
        out.append((txt, gz))
    return out


# ============================================================================================
# Mutators (bytes -> bytes, driven by a random.Random)

TOKENS: list[bytes] = [
    b"\t", b"\n", b"\r", b"\r\n", b"\n\n", b"#", b"", b" ", b"\x0b", b"\x0c", b"\x00",
    b"NaN", b"nan", b"-nan", b"nan(1)", b"inf", b"-inf", b"Infinity", b"+inf",
    b"1e309", b"-1e309", b"3.5e38", b"-4e38", b"3.4028235e38", b"1e-320", b"1e38",
    b"99999999999999999999", b"9007199254740992", b"-9007199254740993",
    b"9223372036854775807", b"-9223372036854775808", b"18446744073709551616",
    b"0x7f", b"0X1F", b"0xFFFFFFFFFFFFFF85", b"0x8000000000000000", b"+5", b"1_000",
    b"\xd9\xa1\xd9\xa2", b"\xef\xbc\x91", b"-0", b"0", b"1", b"-1", b"127", b"128", b"-127",
    b"-128", b"65535", b"65536", b"100000", b"100001", b"32768", b"-32768",
    b"1234567890123456", b"12345678901234567", b"0000000000000000", b"1.5", b"-", b".",
    b"1e", b"e5", b"1,5", b"TYPE_", b"TYPE_WIFI", b"TYPE_BEACON", b"TYPE_WAYPOINT",
    b"TYPE_ACCELEROMETER", b"TYPE_MAGNETIC_FIELD_UNCALIBRATED", b"TYPE_GYROSCOPE",
    b"TYPE_ROTATION_VECTOR", b"TYPE_BLUE", b"TYPE_X1_Y", b"type_wifi", b"TYPE_WIFI ",
    b"TYPE_WIFI\x00", b"TYPE_ACCELEROMETER\x00", b"TYPE_\xc3\x89", b"T" * 60,
    b"\xff", b"\xfe\xff", b"\xed\xa0\x80", b"\xc0\x80", b"\xf4\x90\x80\x80", b"\xe2\x80",
    b"\xef\xbb\xbf", b"\xc2\x85", b"\xe2\x80\xa8", b"\xc2\xa0",
    b"aa:bb:cc:dd:ee:ff", b"AA-BB-CC-DD-EE-FF", b"AABBCCDDEEFF", b"gg:hh:ii:jj:kk:ll",
    b"aa:bb:cc:dd:ee:ff:00", b" aa:bb:cc:dd:ee:ff ", b"#\tstartTime:" + b"9" * 5000,
    b"#\ttype:\xff\tresolution:1e999", b"#\tstartTime:" + b"9" * 30, b"#\tendTime:-5",
    b"#\tstartTime:+1_000", b"1" * 5000, b"9" * 400 + b".5",
]
INVALID_UTF8 = [b"\xff", b"\xfe", b"\x80", b"\xc3", b"\xed\xa0\x80", b"\xc0\xaf",
                b"\xf8\x88\x80\x80\x80", b"\xf4\x90\x80\x80", b"\xe2\x28\xa1", b"\xf0\x9f\x98"]


def _pos(data: bytes, rng: random.Random) -> int:
    return rng.randint(0, len(data))


def _lines(data: bytes) -> list[bytes]:
    return data.split(b"\n")


def m_flip_bits(data, rng):
    if not data:
        return data
    b = bytearray(data)
    for _ in range(rng.randint(1, 8)):
        i = rng.randrange(len(b))
        b[i] ^= 1 << rng.randrange(8)
    return bytes(b)


def m_set_bytes(data, rng):
    if not data:
        return data
    b = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        b[rng.randrange(len(b))] = rng.choice([0, 9, 10, 13, 35, 0x80, 0xff, rng.randrange(256)])
    return bytes(b)


def m_truncate(data, rng):
    return data[:_pos(data, rng)]


def m_chop_head(data, rng):
    return data[_pos(data, rng):]


def m_insert_garbage(data, rng):
    i = _pos(data, rng)
    junk = bytes(rng.randrange(256) for _ in range(rng.randint(1, 64)))
    return data[:i] + junk + data[i:]


def m_insert_token(data, rng):
    i = _pos(data, rng)
    return data[:i] + rng.choice(TOKENS) + data[i:]


def m_delete_range(data, rng):
    i = _pos(data, rng)
    return data[:i] + data[i + rng.randint(1, 200):]


def m_duplicate_range(data, rng):
    i, j = sorted((_pos(data, rng), _pos(data, rng)))
    j = min(j, i + 2000)
    k = _pos(data, rng)
    return data[:k] + data[i:j] + data[k:]


def m_invalid_utf8(data, rng):
    i = _pos(data, rng)
    return data[:i] + rng.choice(INVALID_UTF8) + data[i:]


def m_swap_separators(data, rng):
    choice = rng.randrange(7)
    if choice == 0:
        return data.replace(b"\n", b"\r\n")
    if choice == 1:
        return data.replace(b"\n", b"\r")
    idx = [m.start() for m in re.finditer(rb"[\t\n]", data)]
    if not idx:
        return data
    b = bytearray(data)
    for _ in range(rng.randint(1, 5)):
        i = rng.choice(idx)
        b[i] = {2: 9 if b[i] == 10 else 10, 3: 13, 4: 32, 5: 44, 6: 0}[choice]
    return bytes(b)


def m_replace_field(data, rng):
    """Replace one tab-separated field of a random line by a dangerous token."""
    lines = _lines(data)
    k = rng.randrange(len(lines))
    fields = lines[k].split(b"\t")
    fields[rng.randrange(len(fields))] = rng.choice(TOKENS)
    lines[k] = b"\t".join(fields)
    return b"\n".join(lines)


def m_field_count(data, rng):
    lines = _lines(data)
    k = rng.randrange(len(lines))
    fields = lines[k].split(b"\t")
    if rng.random() < 0.5 and len(fields) > 1:
        del fields[rng.randrange(len(fields))]
    else:
        fields.insert(rng.randint(0, len(fields)), rng.choice(TOKENS))
    lines[k] = b"\t".join(fields)
    return b"\n".join(lines)


def m_change_type(data, rng):
    lines = _lines(data)
    k = rng.randrange(len(lines))
    fields = lines[k].split(b"\t")
    if len(fields) > 1:
        fields[1] = (rng.choice(sorted(DOCUMENTED_TYPES)).encode() if rng.random() < 0.5
                     else rng.choice(TOKENS))
    lines[k] = b"\t".join(fields)
    return b"\n".join(lines)


def m_shuffle_lines(data, rng):
    lines = _lines(data)
    choice = rng.randrange(3)
    if choice == 0:
        rng.shuffle(lines)
    elif choice == 1:
        k = rng.randrange(len(lines))
        lines[k:k] = [lines[k]] * rng.randint(1, 3)
    else:
        lines.reverse()
    return b"\n".join(lines)


def m_ends(data, rng):
    choice = rng.randrange(4)
    if choice == 0:
        return data.rstrip(b"\n")
    if choice == 1:
        return data + b"\n" * rng.randint(1, 3)
    if choice == 2:
        return b"\xef\xbb\xbf" + data  # a byte-order mark
    return data + rng.choice(TOKENS)


TEXT_MUTATORS: list[Callable[[bytes, random.Random], bytes]] = [
    m_flip_bits, m_set_bytes, m_truncate, m_chop_head, m_insert_garbage, m_insert_token,
    m_delete_range, m_duplicate_range, m_invalid_utf8, m_swap_separators, m_replace_field,
    m_replace_field, m_replace_field, m_field_count, m_change_type, m_shuffle_lines, m_ends,
]


def mutate_text(data: bytes, rng: random.Random) -> bytes:
    for _ in range(rng.choice([1, 1, 1, 2, 2, 3, 4])):
        data = rng.choice(TEXT_MUTATORS)(data, rng)
    return data


def gzip_bytes(text: bytes, rng: random.Random | None = None) -> bytes:
    level = rng.choice([0, 1, 6, 9]) if rng else 6
    return gzip.compress(text, compresslevel=level, mtime=0)


def mutate_gzip(text: bytes, gz: bytes, rng: random.Random) -> bytes:
    """Damage a gzip file (``gz`` is ``text`` compressed)."""
    choice = rng.randrange(14)
    b = bytearray(gz)
    if choice == 0:  # header: magic, method, flags, mtime, xfl, os
        i = rng.randrange(10)
        b[i] ^= 1 << rng.randrange(8)
    elif choice == 1:  # flags claiming FEXTRA/FNAME/FCOMMENT/FHCRC that are not there
        b[3] = rng.choice([1, 2, 4, 8, 16, 31, 0xe0, rng.randrange(256)])
    elif choice == 2:  # deflate body
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(10, max(11, len(b) - 8))] ^= 1 << rng.randrange(8)
    elif choice == 3:  # CRC32
        b[-8 + rng.randrange(4)] ^= 1 << rng.randrange(8)
    elif choice == 4:  # ISIZE
        b[-4 + rng.randrange(4)] ^= 1 << rng.randrange(8)
    elif choice == 5:  # truncated anywhere
        return gz[:rng.randrange(len(gz))]
    elif choice == 6:  # concatenated members (valid)
        return gz + gzip_bytes(mutate_text(text, rng), rng)
    elif choice == 7:  # trailing garbage / zero padding / lone magic
        return gz + rng.choice([bytes(rng.randint(1, 512)), b"\x1f", b"\x1f\x8b",
                                b"\x1f\x8b\x08", bytes(rng.randrange(256) for _ in range(40))])
    elif choice == 8:  # a second member, truncated or damaged
        second = bytearray(gzip_bytes(text, rng))
        if rng.random() < 0.5:
            second = second[:rng.randrange(len(second))]
        else:
            second[rng.randrange(len(second))] ^= 0xff
        return gz + bytes(second)
    elif choice == 9:  # empty members around
        empty = gzip.compress(b"", mtime=0)
        return rng.choice([empty + gz, gz + empty, empty, empty * 3])
    elif choice == 10:  # a valid FEXTRA / FNAME / FCOMMENT header with junk, or a bad FHCRC
        flags = rng.choice([4, 8, 16, 2])
        extra = {4: struct.pack("<H", 5) + b"abcde", 8: b"name\xff\x00", 16: b"c\x00",
                 2: b"\x00\x00"}[flags]
        return bytes([0x1f, 0x8b, 8, flags]) + gz[4:10] + extra + gz[10:]
    elif choice == 11:  # mutated text, valid container
        return gzip_bytes(mutate_text(text, rng), rng)
    elif choice == 12:  # raw zlib or deflate stream, not gzip
        return zlib.compress(text) if rng.random() < 0.5 else gz[10:]
    else:  # body bytes overwritten with a run of zeros or junk
        i = rng.randrange(10, max(11, len(b)))
        n = rng.randint(1, 64)
        b[i:i + n] = bytes(n) if rng.random() < 0.5 else bytes(rng.randrange(256)
                                                              for _ in range(n))
    return bytes(b)


# ============================================================================================
# Checking traces


def _ref_dtypes() -> dict[str, list]:
    sensors = empty_table(SENSOR_COLUMNS, SENSOR_DTYPES)
    sensors["stream"] = stream_category([])
    return {"sensors": list(sensors.dtypes),
            "wifi": list(empty_table(WIFI_COLUMNS, WIFI_DTYPES).dtypes),
            "ble": list(empty_table(BLE_COLUMNS, BLE_DTYPES).dtypes),
            "waypoints": list(empty_table(WAYPOINT_COLUMNS, WAYPOINT_DTYPES).dtypes)}


_REF_DTYPES = _ref_dtypes()
_COLUMNS = {"sensors": SENSOR_COLUMNS, "wifi": WIFI_COLUMNS, "ble": BLE_COLUMNS,
            "waypoints": WAYPOINT_COLUMNS}
_DTYPES = {"sensors": SENSOR_DTYPES, "wifi": WIFI_DTYPES, "ble": BLE_DTYPES,
           "waypoints": WAYPOINT_DTYPES}


def table_problems(trace: Trace, *, walkline: bool = False) -> list[str]:
    """Broken invariants of a parsed trace's tables and report (empty list: none)."""
    p: list[str] = []
    arrays: dict[str, dict[str, np.ndarray]] = {}
    for name, cols in _COLUMNS.items():
        frame = getattr(trace, name)
        if tuple(frame.columns) != cols:
            p.append(f"columns: {name} has {list(frame.columns)}")
            continue
        if list(frame.dtypes) != _REF_DTYPES[name]:
            p.append(f"dtypes: {name} has {dict(frame.dtypes.astype(str))}")
            continue
        if not isinstance(frame.index, pd.RangeIndex) or frame.index.start != 0:
            p.append(f"index: {name} index is not 0..n-1")
        arrays[name] = a = {}
        for c, series in frame.items():
            if c == "stream":
                a[c] = series.cat.codes.to_numpy()
            elif c in _DTYPES[name]:
                a[c] = series.to_numpy()
            else:  # strings: object arrays, NaN for missing
                a[c] = series.to_numpy(dtype=object, na_value=None)
                if any(v is None for v in a[c]):
                    p.append(f"null_string: {name}.{c} has missing values")
    if p:
        return p
    s = arrays["sensors"]
    code, t = s["stream"], s["t_ms"]
    if (code < 0).any():
        p.append("sensors: unknown stream")
    if not all(np.isfinite(s[c]).all() for c in "xyz"):
        p.append("non_finite_sensor: x/y/z not finite")
    bias = np.column_stack([s["bx"], s["by"], s["bz"]])
    unc = np.isin(code, _UNCAL)
    if not np.isfinite(bias[unc]).all():
        p.append("non_finite_sensor: bias of an uncalibrated stream not finite")
    if not np.isnan(bias[~unc]).all():
        p.append("sensors: bias of a calibrated stream is not NaN")
    if len(t) > 1:
        d_code, d_t = np.diff(code.astype(np.int64)), np.diff(t)
        if (d_code < 0).any() or ((d_code == 0) & (d_t <= 0)).any():
            p.append("order: sensors not sorted by (stream, t_ms) without repeats")
    if (t < 0).any():
        p.append("sensors: negative time")
    if (s["accuracy"] == -128).any():
        p.append("range: accuracy -128")

    w = arrays["wifi"]
    lo, hi = RSSI_RANGE_DBM
    if len(w["scan_t_ms"]):
        keys = list(zip(w["scan_t_ms"].tolist(), w["bssid"].tolist()))
        if any(x >= y for x, y in itertools.pairwise(keys)):
            p.append("order: wifi not sorted by (scan_t_ms, bssid) without repeats")
        if not all(_MAC.fullmatch(x) for x in w["bssid"]):
            p.append("wifi: bssid not normalized")
        known = w["freq_mhz"] != 0 if walkline else True  # a walk-line log may omit it
        if not (((w["rssi_dbm"] >= lo) & (w["rssi_dbm"] <= hi)).all()
                and ((w["freq_mhz"] >= 1) & (w["freq_mhz"] <= 100_000))[known].all()):
            p.append("range: wifi rssi/frequency")
        if not (w["age_ms"] == w["scan_t_ms"] - w["last_seen_ms"]).all():
            p.append("wifi: age_ms != scan_t_ms - last_seen_ms")
    b = arrays["ble"]
    if len(b["t_ms"]):
        if (np.diff(b["t_ms"]) < 0).any():
            p.append("order: ble not sorted by t_ms")
        if not (np.isfinite(b["distance_m"])  # a walk-line log may omit it: NaN
                | (np.isnan(b["distance_m"]) if walkline else False)).all():
            p.append("non_finite: ble distance")
        if any(k != f"{u}:{ma}:{mi}" for k, u, ma, mi in zip(b["key"], b["uuid"], b["major"],
                                                            b["minor"])):
            p.append("ble: key != uuid:major:minor")
        if not (((b["major"] >= 0) & (b["major"] <= 65535) & (b["minor"] >= 0)
                 & (b["minor"] <= 65535) & (b["rssi_dbm"] >= lo) & (b["rssi_dbm"] <= hi)).all()):
            p.append("range: ble major/minor/rssi")
    wp = arrays["waypoints"]
    if len(wp["t_ms"]):
        if (np.diff(wp["t_ms"]) < 0).any():
            p.append("order: waypoints not sorted by t_ms")
        if not (np.isfinite(wp["x_m"]).all() and np.isfinite(wp["y_m"]).all()):
            p.append("non_finite: waypoint x/y")

    h = trace.header
    for v in (h.start_ms, h.end_ms):
        if v is not None and not (isinstance(v, int) and 0 <= v < 2**63):
            p.append(f"header: start/end time {v!r} does not fit the store's int64")
    r = trace.report
    if r.accounted_lines() != r.lines_total:
        p.append(f"accounting: accounted {r.accounted_lines()} != lines_total {r.lines_total}")
    counts = [r.header_lines, r.blank_lines, *r.records.values(), *r.skipped.values(),
              *r.bad.values(), *r.dropped.values()]
    listed = [*r.skipped.values(), *r.bad.values()] + ([] if walkline else [*r.records.values()])
    if any(c < 0 for c in counts) or any(c == 0 for c in listed):
        p.append("accounting: a negative or zero count is listed")
    n_s, n_w, n_b, n_wp = (len(arrays[k]["t_ms" if k != "wifi" else "scan_t_ms"])
                           for k in ("sensors", "wifi", "ble", "waypoints"))
    if walkline:
        if set(r.bad) - {"non_numeric", "out_of_range", "field_count", "bad_bssid",
                         "time_outlier"}:
            p.append(f"report: unexpected bad reasons {sorted(r.bad)}")
        if (n_w + r.dropped.get("duplicate_bssid_in_scan", 0) != r.records.get("WIFI_ROW", 0)
                or n_b + r.dropped.get("duplicate_beacon", 0) != r.records.get("BLE_ROW", 0)):
            p.append("counts: wifi/ble rows + dropped != walk-line radio rows")
        if n_wp and (np.diff(wp["t_ms"]) <= 0).any():
            p.append("order: walk-line vertex times not strictly increasing")
        return p
    if set(r.records) - DOCUMENTED_TYPES:
        p.append(f"report: records of undocumented types {set(r.records) - DOCUMENTED_TYPES}")
    bad_skipped = [k for k in r.skipped if k in DOCUMENTED_TYPES or not _TYPE_NAME.fullmatch(k)]
    if bad_skipped:
        p.append(f"skipped_name: skipped types that are documented or not TYPE_ names: "
                 f"{[k[:60] for k in bad_skipped]}")
    if set(r.bad) - BAD_REASONS:
        p.append(f"report: unknown bad reasons {sorted(set(r.bad) - BAD_REASONS)}")
    n_sensor = sum(v for k, v in r.records.items() if k in SENSOR_STREAMS)
    if n_s + r.dropped.get("duplicate_timestamp", 0) != n_sensor:
        p.append("counts: sensor rows + dropped != sensor records")
    if n_w + r.dropped.get("duplicate_bssid_in_scan", 0) != r.records.get("TYPE_WIFI", 0):
        p.append("counts: wifi rows + dropped != wifi records")
    if (n_b + r.dropped.get("duplicate_beacon", 0) != r.records.get("TYPE_BEACON", 0)
            or n_wp + r.dropped.get("duplicate_waypoint", 0)
            != r.records.get("TYPE_WAYPOINT", 0)):
        p.append("counts: ble/waypoint rows != records")
    return p


def same_trace(a: Trace, b: Trace) -> str | None:
    """None if the two parses are identical, else what differs."""
    for name in ("sensors", "wifi", "ble", "waypoints"):
        x, y = getattr(a, name), getattr(b, name)
        if x.equals(y) and list(x.dtypes) == list(y.dtypes) and x.index.equals(y.index):
            continue  # (equals: same values, NaN == NaN, same dtypes per block)
        try:
            pd.testing.assert_frame_equal(x, y, check_exact=True)
        except AssertionError as err:
            return f"{name}: {' '.join(str(err).split())[:300]}"
        return f"{name}: differs"
    if a.report != b.report:
        return f"report: {a.report} != {b.report}"
    if repr(a.header) != repr(b.header):
        return "header differs"
    if a.trace_id != b.trace_id:
        return "trace_id differs"
    return None


def _runtime_warnings(caught) -> list[str]:
    return [f"warning: {w.category.__name__}: {w.message}" for w in caught
            if issubclass(w.category, RuntimeWarning)]


def _line_count(text: bytes) -> int:
    return text.count(b"\n") + (1 if text and not text.endswith(b"\n") else 0)


def check_text_batch(texts: Sequence[bytes], *, alone: Sequence[bool] | None = None,
                     path_prefix: str = "fuzz") -> list[list[str]]:
    """Problems per text: parse all texts as one lenient batch, then each alone (strict, and
    lenient where ``alone[i]``), and check every invariant."""
    paths = [f"{path_prefix}{i}.txt" for i in range(len(texts))]
    alone = list(alone) if alone is not None else [False] * len(texts)
    problems: list[list[str]] = [[] for _ in texts]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        joined = False  # a text naming two walks refuses the batch (each alone: checked)
        try:
            batch = parse_traces(list(texts), paths)
        except Exception as err:  # noqa: BLE001 - the point is to catch anything
            batch = None
            batch_error = f"lenient_raised: batch: {type(err).__name__}: {err}"
            joined = isinstance(err, SurveyFormatError) and err.reason == "header_conflict"
    warned = _runtime_warnings(caught)
    if batch is None or warned:  # find which text is to blame
        for i, text in enumerate(texts):
            problems[i] = check_text(text, paths[i])
        if not any(problems) and not (joined and not warned):
            problems = [[batch_error if batch is None else warned[0]] for _ in texts]
        return problems
    for i, text in enumerate(texts):
        problems[i] = _check_parsed(text, paths[i], batch[i], compare_alone=alone[i])
    return problems


def check_text(text: bytes, path: str = "fuzz.txt") -> list[str]:
    """Problems of one trace text parsed alone (lenient and strict)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            lenient = parse_trace_bytes(text, path=path)
        except SurveyFormatError as err:
            if err.reason != "header_conflict":
                return [f"lenient_raised: {err.reason}: {err}"]
            # two walks' headers in one text: refused whole, in both modes alike
            return _refused_in_both_modes(
                lambda: parse_trace_bytes(text, path=path, strict=True), str(err))
        except Exception as err:  # noqa: BLE001
            return [f"lenient_raised: {type(err).__name__}: {err}"]
    return _runtime_warnings(caught) + _check_parsed(text, path, lenient, compare_alone=False)


def _check_parsed(text: bytes, path: str, lenient: Trace, *, compare_alone: bool) -> list[str]:
    p = table_problems(lenient)
    if lenient.report.lines_total != _line_count(text):
        p.append(f"accounting: lines_total {lenient.report.lines_total} != "
                 f"{_line_count(text)} lines in the text")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if compare_alone:
            try:
                single = parse_trace_bytes(text, path=path)
                diff = same_trace(single, lenient)
                if diff:
                    p.append(f"batch_differs: alone vs in a batch: {diff}")
            except Exception as err:  # noqa: BLE001
                p.append(f"lenient_raised: {type(err).__name__}: {err}")
        p += _strict_problems(lambda: parse_trace_bytes(text, path=path, strict=True), lenient,
                              damaged=False)
    return p + _runtime_warnings(caught)


def _strict_problems(call, lenient: Trace, *, damaged: bool) -> list[str]:
    r = lenient.report
    try:
        strict = call()
    except SurveyFormatError as err:
        if not r.bad and not damaged:
            return [f"strict_mismatch: strict raised on a text lenient found clean: {err}"]
        if not damaged and str(err) != r.messages[0]:
            return [(f"strict_mismatch: strict {str(err)[:200]!r} != lenient first message "
                     f"{r.messages[0][:200]!r}")]
        return []
    except Exception as err:  # noqa: BLE001
        return [f"strict_raised: {type(err).__name__}: {str(err)[:300]}"]
    if r.bad or damaged:
        return [f"strict_mismatch: strict accepted what lenient reported bad: {r.bad}"]
    diff = same_trace(strict, lenient)
    return [f"strict_mismatch: strict and lenient results differ: {diff}"] if diff else []


def check_trace_files(paths: Sequence[Path], store: Path | None = None) -> list[list[str]]:
    """Problems per trace file (plain or gzip): ``read_trace`` strict and lenient, and
    ``iter_traces`` over all of them (batched) against the single reads; with ``store``, a
    lenient ingest of all of them into a new store there must not raise."""
    problems: list[list[str]] = []
    singles: list[Trace | None] = []
    for path in paths:
        p: list[str] = []
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            single = None
            try:
                single = read_trace(path)
            except SurveyFormatError as err:
                if (err.reason == "gzip" and "damaged gzip stream" in str(err)
                        or err.reason == "header_conflict"):
                    p += _refused_in_both_modes(
                        lambda path=path: read_trace(path, strict=True), str(err))
                elif err.reason == "empty":  # no record at all: strict refuses it too
                    p += _strict_refuses(lambda path=path: read_trace(path, strict=True))
                else:  # only unreadable files, streams damaged inside, joined walks and
                    # files without a single record may
                    p.append(f"lenient_raised: {err.reason}: {err}")
            except Exception as err:  # noqa: BLE001
                p.append(f"lenient_raised: {type(err).__name__}: {err}")
            try:  # a size limit below the text: refused with the project's error
                read_trace(path, max_bytes=4096)
            except SurveyFormatError:
                pass
            except Exception as err:  # noqa: BLE001
                p.append(f"lenient_raised: max_bytes: {type(err).__name__}: {err}")
            if single is not None:
                p += table_problems(single)
                notes = [m for m in single.report.messages if not re.match(r".*:\d+: ", m)]
                damaged = bool(notes)
                if damaged and not single.report.messages[0].endswith("kept the readable part"):
                    p.append("report: the gzip note is not the first message")
                p += _strict_problems(lambda path=path: read_trace(path, strict=True), single,
                                      damaged=damaged)
        p += _runtime_warnings(caught)
        problems.append(p)
        singles.append(single)
    try:
        items = list(iter_traces(paths, batch_bytes=1 << 16))
    except Exception as err:  # noqa: BLE001
        return [p + [f"lenient_raised: iter_traces: {type(err).__name__}: {err}"]
                for p in problems]
    for p, single, item in zip(problems, singles, items):
        if single is not None:
            diff = same_trace(single, item) if isinstance(item, Trace) else "a ReadFailure"
            if diff:
                p.append(f"batch_differs: read_trace vs iter_traces: {diff}")
        elif isinstance(item, Trace):
            p.append("batch_differs: iter_traces read what read_trace refused")
    if store is not None:
        problems = [p + check_ingest(paths, store) for p in problems]
    return problems


def _strict_refuses(strict_read: Callable[[], object]) -> list[str]:
    """A file lenient mode refuses as holding no record is refused by strict mode too (at its
    first bad line, or as empty)."""
    try:
        strict_read()
    except SurveyFormatError:
        return []
    except Exception as err:  # noqa: BLE001
        return [f"strict_raised: {type(err).__name__}: {err}"]
    return ["strict_mismatch: strict read what lenient refused as holding no record"]


def _refused_in_both_modes(strict_read: Callable[[], object], lenient: str) -> list[str]:
    """A gzip stream damaged inside, or two walks' headers in one file, is refused by strict
    mode (``strict_read``) too, with the same text."""
    try:
        strict_read()
    except SurveyFormatError as err:
        return [] if str(err) == lenient else [f"strict_mismatch: {err} vs lenient {lenient}"]
    except Exception as err:  # noqa: BLE001
        return [f"strict_raised: {type(err).__name__}: {err}"]
    return ["strict_mismatch: strict read what lenient refused as damaged"]


def check_ingest(paths: Sequence[Path], store: Path) -> list[str]:
    """A lenient ingest of ``paths`` into a new store must not raise (a bad file is a failed
    outcome, never an exception)."""
    from survey.ingest import ingest

    shutil.rmtree(store, ignore_errors=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            ingest(paths, store)
        except Exception as err:  # noqa: BLE001
            return [f"ingest_raised: {type(err).__name__}: {str(err)[:200]}"]
    return []


# ============================================================================================
# Walk-line reader

PLAN = {
    "type": "FeatureCollection",
    "properties": {"site_id": "siteW", "floor_name": "F2", "device_model": "Pixel"},
    "features": [
        {"type": "Feature",
         "geometry": {"type": "LineString", "coordinates": [[0, 0], [3, 0], [3, 4]]},
         "properties": {"walk_id": "a", "sensor_log": "a.csv", "wifi_log": "a.wifi.csv",
                        "ble_log": "a.ble.csv", "start_ms": 1_700_000_000_000,
                        "end_ms": 1_700_000_007_000}},
        {"type": "Feature",
         "geometry": {"type": "LineString", "coordinates": [[0, 0], [0, 10.5]]},
         "properties": {"walk_id": "b", "sensor_log": "b.csv",
                        "vertex_times_ms": [1_700_000_000_000, 1_700_000_001_980]}},
    ],
}
_CSV_A_COLS = ["t_ms", "acc_x", "acc_y", "acc_z", "mag_x", "mag_y", "mag_z", "rot_x", "rot_y",
               "rot_z", "mag_uncal_x", "mag_uncal_y", "mag_uncal_z", "mag_bias_x", "mag_bias_y",
               "mag_bias_z", "accuracy"]
_CSV_B_COLS = ["t_ms", "gyro_x", "gyro_y", "gyro_z", "acc_uncal_x", "acc_uncal_y", "acc_uncal_z",
               "acc_bias_x", "acc_bias_y", "acc_bias_z"]


def sensor_csv(columns: list[str], n: int = 25, seed: int = 1) -> bytes:
    rng = np.random.default_rng(seed)
    rows = [",".join(columns)]
    for i in range(n):
        vals = [f"{v:.6f}" for v in rng.normal(0, 5, len(columns) - 1)]
        if columns[-1] == "accuracy":
            vals[-1] = str(i % 4)
        rows.append(",".join([str(1_700_000_000_000 + 20 * i)] + vals))
    return ("\n".join(rows) + "\n").encode()


CSV_A = sensor_csv(_CSV_A_COLS)
CSV_B = sensor_csv(_CSV_B_COLS, seed=2)
#: Walk a's radio logs (docs/walkline_format.md): two Wi-Fi scans, BLE sightings.
WIFI_A = (b"t_ms,bssid,rssi_dbm,freq_mhz,ssid,last_seen_ms\n"
          b"1700000001000,aa:bb:cc:00:00:01,-61,2412,mall,1700000000900\n"
          b"1700000001000,AA-BB-CC-00-00-02,-75.4,5180,\"a,b\",1700000001000\n"
          b"1700000001000,aabbcc000003,-88,,,\n"
          b"1700000003000,aa:bb:cc:00:00:01,-58,2412,mall,1700000003000\n")
BLE_A = (b"t_ms,uuid,major,minor,rssi_dbm,tx_power_dbm,distance_m,mac,last_seen_ms\n"
         b"1700000001500,FDA50693-A4E2-4FB1-AFCF-C6EB07647825,10,1,-70,-59,2.5,"
         b"AA:00:00:00:00:01,1700000001500\n"
         b"1700000002500,fda50693-a4e2-4fb1-afcf-c6eb07647825,10,2,-81,,,,\n")
PLAN_BYTES = json.dumps(PLAN, indent=1).encode()

CSV_TOKENS = [b"", b"nan", b"NaN", b"inf", b"-inf", b"1e309", b"1e30", b"-1e30", b"3.5e38",
              b"1e19", b"99999999999999999999", b"9.3e18", b"-5", b"1.5", b"300", b"-129",
              b"128", b"127", b"2020-01-01", b"2020-01-01T00:00:00", b"9999-12-31 23:59:59",
              b"00:00:01", b"true", b"false", b"null", b"NA", b"\"\"", b"\"1,2\"", b"\"a\nb\"",
              b"\"", b"0x10", b"1_0", b"\xff", b"\xed\xa0\x80", b"t_ms", b"acc_x", b"accuracy",
              b" ", b"\r", b"\t", b"1" * 400]
JSON_VALUES: list = [None, True, False, 0, -1, 1, 1.5, -1e308, 1e308, float("nan"),
                     float("inf"), 10**30, 10**400, -(10**20), "", "abc", "a.csv", "b.csv",
                     "a.csv\x00", "missing.csv", "LineString", "FeatureCollection", "Feature",
                     [], [[]], [0], [[0, 0]], [[0, 0], [1]], [[0, 0], [1, 1, 1]],
                     [[0, 0], ["x", 1]], [[0, 0], [[1], 2]], [[1e308, 0], [-1e308, 0]],
                     [1_700_000_000_000, 1_700_000_000_000.5],
                     [10**30, 10**31, 10**32], [0.5, 0.7, 0.9], [-5, 0, 5], {},
                     {"a": 1}, {"type": "LineString", "coordinates": [[0, 0], [1, 1]]}]


def _json_nodes(node, out: list | None = None) -> list[tuple[object, object]]:
    """(container, key) of every value inside a parsed JSON document."""
    out = [] if out is None else out
    items = node.items() if isinstance(node, dict) else enumerate(node) \
        if isinstance(node, list) else ()
    for k, v in items:
        out.append((node, k))
        _json_nodes(v, out)
    return out


def mutate_plan(rng: random.Random) -> bytes:
    """A damaged walk plan: its JSON bytes mutated, or one node of the tree replaced."""
    choice = rng.randrange(10)
    if choice < 3:
        return mutate_text(PLAN_BYTES, rng)
    if choice == 3:
        depth = rng.choice([10, 1000, 100_000])
        return b"[" * depth + b"]" * depth if rng.random() < 0.5 else \
            b'{"type":"FeatureCollection","features":' + b"[" * depth + b"]" * depth + b"}"
    plan = json.loads(PLAN_BYTES)
    for _ in range(rng.randint(1, 3)):
        nodes = _json_nodes(plan)
        if not nodes:
            break
        parent, key = rng.choice(nodes)
        if isinstance(parent, dict) and rng.random() < 0.2:
            del parent[key]
        elif isinstance(parent, list) and rng.random() < 0.1:
            parent.append(copy.deepcopy(parent[key]))
        else:
            parent[key] = copy.deepcopy(rng.choice(JSON_VALUES))  # never shared: no cycles
    if rng.random() < 0.1:
        plan = rng.choice([[], "x", 5, None, {"type": "FeatureCollection", "features": {}},
                           {"type": "FeatureCollection", "features": "ab"},
                           {"type": "FeatureCollection", "features": 5},
                           {"type": "FeatureCollection", "properties": [1],
                            "features": PLAN["features"]}])
    return json.dumps(plan).encode()


def mutate_csv(data: bytes, rng: random.Random) -> bytes:
    choice = rng.randrange(8)
    if choice < 3:
        return mutate_text(data, rng)
    lines = data.split(b"\n")
    for _ in range(rng.randint(1, 3)):
        k = rng.randrange(len(lines))
        fields = lines[k].split(b",")
        op = rng.randrange(5)
        if op == 0:
            fields[rng.randrange(len(fields))] = rng.choice(CSV_TOKENS)
        elif op == 1 and len(fields) > 1:
            del fields[rng.randrange(len(fields))]
        elif op == 2:
            fields.insert(rng.randrange(len(fields) + 1), rng.choice(CSV_TOKENS))
        elif op == 3:  # header games: duplicate, rename or drop a column name
            head = lines[0].split(b",")
            i = rng.randrange(len(head))
            head[i] = rng.choice([head[rng.randrange(len(head))], b"", b"t_ms", b"accuracy",
                                  b"mag_bias_x", b"\xff"])
            lines[0] = b",".join(head)
            continue
        else:
            lines.insert(k, rng.choice([b"", b"\r", b",,,", lines[k]]))
            continue
        lines[k] = b",".join(fields)
    return b"\n".join(lines)


def check_walk_plan(folder: Path) -> list[str]:
    """Problems of ``folder/plan.geojson`` (with its CSVs) read by ``read_walk_plan``."""
    plan = folder / "plan.geojson"
    p: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            flag = is_walk_plan(plan)
            if not isinstance(flag, bool):
                p.append(f"is_walk_plan: returned {flag!r}")
        except Exception as err:  # noqa: BLE001
            p.append(f"is_walk_plan_raised: {type(err).__name__}: {str(err)[:200]}")
        for strict in (False, True):
            try:
                walks = read_walk_plan(plan, strict=strict)
            except SurveyFormatError:
                continue
            except Exception as err:  # noqa: BLE001
                p.append(f"walkline_raised: strict={strict}: {type(err).__name__}: "
                         f"{str(err)[:200]}")
                continue
            for trace, _, identity in walks:
                p += table_problems(trace, walkline=True)
                if not isinstance(identity, bytes):
                    p.append("walkline: identity is not bytes")
                if strict and trace.report.bad:
                    p.append("strict_mismatch: strict walk-line read kept bad rows")
                h = trace.header
                if not (isinstance(h.start_ms, int) and isinstance(h.end_ms, int)
                        and 0 <= h.start_ms <= h.end_ms < 2**63):
                    p.append(f"walkline: header times {h.start_ms!r}..{h.end_ms!r}")
    return p + _runtime_warnings(caught)


def write_walk_case(folder: Path, plan: bytes = PLAN_BYTES, csv_a: bytes = CSV_A,
                    csv_b: bytes = CSV_B, wifi_a: bytes = WIFI_A, ble_a: bytes = BLE_A) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "plan.geojson").write_bytes(plan)
    for name, data in (("a.csv", csv_a), ("b.csv", csv_b), ("a.wifi.csv", wifi_a),
                       ("a.ble.csv", ble_a)):
        (folder / name).write_bytes(data)


#: A saved CSV stands in for the log of its kind, by its name's ending.
_CSV_ROLES = {".wifi.csv": "wifi_a", ".ble.csv": "ble_a", ".csv": "csv_a"}


def csv_role(name: str) -> str:
    """The :func:`write_walk_case` argument a saved CSV named ``name`` replays as."""
    return next(role for end, role in _CSV_ROLES.items() if name.endswith(end))


# ============================================================================================
# Replaying one input (also what a saved failure must reproduce)

#: One line of each value layout with a non-numeric value: in a batch with these, every layout
#: group fails pyarrow's fast parse and is re-read line by line, so comparing a text parsed
#: alone with the text parsed beside this one compares the two paths.
FORCE_SLOW = b"".join(line + b"\n" for line in [
    b"1\tTYPE_ACCELEROMETER\tx\t0\t0\t3",
    b"1\tTYPE_ACCELEROMETER_UNCALIBRATED\tx\t0\t0\t0\t0\t0\t3",
    b"1\tTYPE_WIFI\ts\t00:11:22:33:44:55\tx\t2412\t1",
    b"1\tTYPE_BEACON\tu\tx\t1\t-59\t-70\t1.0\tm\t1",
    b"1\tTYPE_WAYPOINT\tx\t0",
])


def good_text() -> bytes:
    """A small valid trace (factory, rendered)."""
    from factories import small_trace

    from survey.trace_writer import render_trace

    return render_trace(small_trace(n=12, seed=7)).encode()


def check_text_replay(text: bytes) -> list[str]:
    """Problems of one trace text: parsed alone (lenient, strict) and in a batch after a good
    text and before :data:`FORCE_SLOW` (same result as alone; the good text unaffected)."""
    good = good_text()
    probs = check_text_batch([good, text, FORCE_SLOW], alone=[True, True, False])
    return probs[1] + [f"{q} (in the good text before it)" if ": " in q else q
                       for q in probs[0]]


def check_corrupt_file(path: Path, workdir: Path) -> list[str]:
    """Replay one saved input of ``tests/data/corrupt`` (by its extension)."""
    name = path.name
    workdir.mkdir(parents=True, exist_ok=True)
    if name.endswith(".geojson"):
        write_walk_case(workdir / "plan", plan=path.read_bytes())
        return check_walk_plan(workdir / "plan")
    if name.endswith(".csv"):
        write_walk_case(workdir / "csv", **{csv_role(name): path.read_bytes()})
        return check_walk_plan(workdir / "csv")
    if name.endswith((".txt", ".txt.gz")):
        # read alone and batched (iter_traces) before a file with bad lines
        force = workdir / "force_slow.txt"
        force.write_bytes(FORCE_SLOW)
        problems = check_trace_files([path, force])[0]
        if name.endswith(".txt"):
            problems = check_text_replay(path.read_bytes()) + problems
        return problems
    return [f"unknown corrupt file type: {name}"]


# ============================================================================================
# Minimizing a failing input


def signature(problem: str) -> str:
    """The kind of a problem: text before the first colon (plus the exception type)."""
    head, _, rest = problem.partition(": ")
    if head.endswith("_raised"):
        m = re.search(r"\b([A-Z]\w*(?:Error|Exception|Warning|Invalid))\b", rest)
        return f"{head}:{m.group(1) if m else ''}"
    return head


def minimize(data: bytes, fails: Callable[[bytes], bool], *, budget: int = 200) -> bytes:
    """Shrink ``data`` while ``fails(data)`` stays true: drop runs of lines (ddmin-style), then
    runs of bytes. At most ``budget`` calls of ``fails``."""
    calls = 0
    for unit in (b"\n", b""):
        parts = data.split(b"\n") if unit else [bytes([c]) for c in data]
        if len(parts) > 4000:
            continue
        n = 2
        while len(parts) >= 2 and calls < budget:
            chunk = max(1, len(parts) // n)
            for i in range(0, len(parts), chunk):
                rest = parts[:i] + parts[i + chunk:]
                calls += 1
                if fails(unit.join(rest)):
                    parts, n = rest, max(n - 1, 2)
                    break
                if calls >= budget:
                    break
            else:
                if chunk == 1:
                    break
                n = min(len(parts), 2 * n)
        data = unit.join(parts)
    return data


#: A saved input's file name ending, by kind.
_EXTENSIONS = {"txt": ".txt", "gz": ".txt.gz", "plan": ".geojson", "csv": ".csv",
               "wifi.csv": ".wifi.csv", "ble.csv": ".ble.csv"}


@dataclass
class Failure:
    kind: str  # "txt", "gz", "plan", "csv", "wifi.csv", "ble.csv"
    data: bytes
    problems: list[str]
    seed: int

    @property
    def signature(self) -> str:
        return signature(self.problems[0])

    def filename(self) -> str:
        sig = re.sub(r"[^a-z0-9]+", "-", self.signature.lower()).strip("-")[:40]
        digest = hashlib.sha256(self.data).hexdigest()[:10]
        return f"{self.kind.split('.')[0]}-{sig}-{digest}{_EXTENSIONS[self.kind]}"


def replay_check(kind: str, workdir: Path) -> Callable[[bytes], list[str]]:
    """The check a saved input of this kind is replayed with (see :func:`check_corrupt_file`)."""
    ext = _EXTENSIONS[kind]

    def check(data: bytes) -> list[str]:
        workdir.mkdir(parents=True, exist_ok=True)
        path = workdir / f"replay{ext}"
        path.write_bytes(data)
        return check_corrupt_file(path, workdir)

    return check


def shrink(failure: Failure, workdir: Path, budget: int = 200) -> Failure:
    """Minimize a failure so that its replay still shows the same kind of problem."""
    check = replay_check(failure.kind, workdir)
    sig = failure.signature
    if not any(signature(q) == sig for q in check(failure.data)):
        return failure  # does not reproduce alone (kept as found)
    if failure.kind == "gz":
        return failure
    quick = ((lambda d: check_text_batch([d, FORCE_SLOW], alone=[True, False])[0])
             if failure.kind == "txt" else check)
    data = minimize(failure.data, lambda d: any(signature(q) == sig for q in quick(d)),
                    budget=budget)
    problems = check(data)
    if not any(signature(q) == sig for q in problems):
        return failure
    return Failure(failure.kind, data, problems, failure.seed)


# ============================================================================================
# The runner


@dataclass
class FuzzStats:
    tried: dict[str, int]
    failures: list[Failure]
    seconds: float = 0.0

    @property
    def total(self) -> int:
        return sum(self.tried.values())

    def by_signature(self) -> dict[tuple[str, str], list[Failure]]:
        out: dict[tuple[str, str], list[Failure]] = {}
        for f in self.failures:
            out.setdefault((f.kind, f.signature), []).append(f)
        return out


def run_fuzz(seed: int, workdir: Path, *, texts: int = 0, gz_cases: int = 0,
             walk_cases: int = 0, batch_size: int = 8, compare_all: bool = False,
             sample_files: int | None = 3, full_traces: int = 0, ingest_every: int = 5,
             deadline: float | None = None) -> FuzzStats:
    """One seeded fuzz run; returns the counts of inputs tried per kind and the failures.

    About ``texts`` mutated trace texts are parsed in batches of ``batch_size`` (a quarter of
    each batch unmutated, sometimes with :data:`FORCE_SLOW`), together and alone;
    ``gz_cases`` damaged gzip files (plus ``full_traces`` whole sample traces damaged) are
    read in chunks; ``walk_cases`` damaged walk plans or sensor CSVs are read. The texts of
    the first and every ``ingest_every``-th batch, and the files of the first and every
    ``ingest_every``-th gzip chunk, are also ingested into a scratch store (0: never).
    ``deadline`` (a ``time.monotonic()`` value) stops the run early.
    """
    start = time.monotonic()
    rng = random.Random(seed)
    workdir.mkdir(parents=True, exist_ok=True)
    real = sample_texts(sample_files)
    real_gz = [p.read_bytes() for p in SAMPLE_TRACES[:sample_files]]
    seeds = factory_seeds(workdir / "seeds")
    stats = FuzzStats({"text": 0, "gzip": 0, "walkline": 0}, [])

    def seed_text() -> bytes:
        if real and rng.random() < 0.7:
            return sample_window(rng.choice(real), rng)
        return rng.choice(seeds)[0]

    def over() -> bool:
        return deadline is not None and time.monotonic() > deadline

    # 1. Texts, in batches mixing good and mutated ones.
    n_good = max(1, batch_size // 4)
    n_batches = 0
    while stats.tried["text"] < texts and not over():
        batch, mutated = [], []
        for j in range(batch_size):
            base = seed_text()
            batch.append(mutate_text(base, rng) if j >= n_good else base)
            mutated.append(j >= n_good)
        if rng.random() < 0.25:
            batch[-1], mutated[-1] = FORCE_SLOW, False
        order = list(range(batch_size))
        rng.shuffle(order)
        batch = [batch[i] for i in order]
        mutated = [mutated[i] for i in order]
        results = check_text_batch(batch, alone=[compare_all or not m for m in mutated])
        n_batches += 1
        if ingest_every and n_batches % ingest_every == 1 % ingest_every:  # end to end
            folder = workdir / "ingest"
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            for j, text in enumerate(batch):
                (folder / f"t{j}.txt").write_bytes(text)
            ingest_problems = check_ingest(sorted(folder.glob("*.txt")), workdir / "store")
            results = [r + ingest_problems for r in results]
        stats.tried["text"] += sum(mutated)
        for text, problems in zip(batch, results):
            if problems:
                stats.failures.append(Failure("txt", text, problems, seed))

    # 2. Damaged gzip files (small factory traces and sample windows; a few whole traces).
    gz_dir = workdir / "gz"
    gz_dir.mkdir(exist_ok=True)
    i = n_chunks = 0
    while i < gz_cases + full_traces and not over():
        chunk = []
        for _ in range(min(6, gz_cases + full_traces - i)):
            if i < full_traces and real_gz:
                k = rng.randrange(len(real_gz))
                text, gz = real[k], real_gz[k]
            elif rng.random() < 0.5:
                text, gz = rng.choice(seeds)
            else:
                text = sample_window(rng.choice(real), rng, 600) if real else seeds[0][0]
                gz = gzip_bytes(text, rng)
            chunk.append(mutate_gzip(text, gz, rng))
            i += 1
        paths = []
        for j, data in enumerate(chunk):
            path = gz_dir / f"case{j}.txt.gz"
            path.write_bytes(data)
            paths.append(path)
        n_chunks += 1
        ingest_now = ingest_every and n_chunks % ingest_every == 1 % ingest_every
        results = check_trace_files(paths, store=workdir / "store" if ingest_now else None)
        stats.tried["gzip"] += len(chunk)
        for data, problems in zip(chunk, results):
            if problems:
                stats.failures.append(Failure("gz", data, problems, seed))

    # 3. Walk plans and sensor CSVs (a mutated CSV of either column set stands in as a.csv).
    walk_dir = workdir / "walk"
    while stats.tried["walkline"] < walk_cases and not over():
        if rng.random() < 0.5:
            kind, data = "plan", mutate_plan(rng)
            write_walk_case(walk_dir, plan=data)
        else:  # a sensor CSV stands in as a.csv, a radio log as walk a's
            role, base = rng.choice([("csv_a", CSV_A), ("csv_a", CSV_B), ("wifi_a", WIFI_A),
                                     ("ble_a", BLE_A)])  # not `seed`: the run's, recorded
            kind, data = {"csv_a": "csv", "wifi_a": "wifi.csv", "ble_a": "ble.csv"}[role], \
                mutate_csv(base, rng)
            write_walk_case(walk_dir, **{role: data})
        stats.tried["walkline"] += 1
        problems = check_walk_plan(walk_dir)
        if problems:
            stats.failures.append(Failure(kind, data, problems, seed))
    stats.seconds = time.monotonic() - start
    return stats


def save_failures(stats: FuzzStats, folder: Path, workdir: Path, *, per_signature: int = 1,
                  budget: int = 200) -> list[Path]:
    """Minimize up to ``per_signature`` failures of each kind of problem and save them in
    ``folder`` (e.g. ``tests/data/corrupt``). Returns the files written."""
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for (_kind, _sig), failures in sorted(stats.by_signature().items()):
        for failure in failures[:per_signature]:
            small = shrink(failure, workdir / "shrink", budget=budget)
            path = folder / small.filename()
            path.write_bytes(small.data)
            written.append(path)
    return written
