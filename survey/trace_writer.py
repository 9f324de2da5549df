"""Render a :class:`~survey.trace_format.Trace` to the trace text format (``.txt`` / ``.txt.gz``).

Used by the simulator and by round-trip tests. The output follows the real logger's layout:
header lines first, ``endTime`` last, records ordered by time except that waypoint lines are
written late (``waypoint_delay_ms`` after their timestamp), as the real app does.
Floats are written with 9 significant digits, so float32 values survive a round trip exactly.
"""

from __future__ import annotations

import gzip
import io
import os
from pathlib import Path

import numpy as np
import pandas as pd

from .trace_format import STREAM_TO_RECORD, UNCALIBRATED_STREAMS, Trace, TraceHeader


def format_floats(values: np.ndarray) -> np.ndarray:
    """Values as text of 9 significant digits (float32 values survive a round trip)."""
    return np.array([format(v, ".9g") for v in np.asarray(values, dtype=np.float64).tolist()],
                    dtype=object)


def _fmt_int(values: np.ndarray) -> np.ndarray:
    return np.asarray(values, dtype=np.int64).astype(str).astype(object)


def _fmt_str(values) -> np.ndarray:
    return np.asarray(pd.Series(values, dtype="str").fillna(""), dtype=object)


def header_lines(header: TraceHeader) -> tuple[list[str], list[str]]:
    """Header lines that open the file and the ``endTime`` line that closes it."""
    def val(v: object) -> str:
        return "" if v is None else str(v)

    head = []
    if header.start_ms is not None:
        head.append(f"#\tstartTime:{header.start_ms}")
    head.append(f"#\tSiteID:{val(header.site_id)}\tSiteName:{val(header.site_name)}"
                f"\tFloorId:{val(header.floor_id)}\tFloorName:{val(header.floor_name)}")
    head.append(f"#\tBrand:{val(header.brand)}\tModel:{val(header.model)}"
                f"\tAndroidName:{val(header.android_version)}\tAPILevel:{val(header.api_level)}\t")
    for s in header.sensors:
        head.append(f"#\ttype:{s.type_code}\tname:{s.name}\tversion:{s.version}\tvendor:{s.vendor}"
                    f"\tresolution:{s.resolution:.9g}\tpower:{s.power_ma:.9g}"
                    f"\tmaximumRange:{s.maximum_range:.9g}")
    if header.app_version is not None:
        head.append(f"#\tVersionName:{header.app_version}\t")
    for key, value in header.extra.items():
        head.append(f"#\t{key}:{value}")
    tail = [f"#\tendTime:{header.end_ms}"] if header.end_ms is not None else []
    return head, tail


def render_records(trace: Trace, waypoint_delay_ms: int = 800) -> list[str]:
    """Record lines of ``trace`` in file order (time order, waypoints written late)."""
    parts: list[tuple[np.ndarray, np.ndarray]] = []  # (sort key ms, line)

    sensors = trace.sensors
    for stream, rows in sensors.groupby("stream", observed=True, sort=False):
        record = STREAM_TO_RECORD[str(stream)]
        cols = [_fmt_int(rows["t_ms"]), np.full(len(rows), record, dtype=object)]
        cols += [format_floats(rows[c].to_numpy()) for c in ("x", "y", "z")]
        if record in UNCALIBRATED_STREAMS:
            cols += [format_floats(rows[c].to_numpy()) for c in ("bx", "by", "bz")]
        cols.append(_fmt_int(rows["accuracy"]))
        parts.append((rows["t_ms"].to_numpy(np.int64), _join(cols)))

    wifi = trace.wifi
    if len(wifi):
        cols = [_fmt_int(wifi["scan_t_ms"]), np.full(len(wifi), "TYPE_WIFI", dtype=object),
                _fmt_str(wifi["ssid"]), _fmt_str(wifi["bssid"]), _fmt_int(wifi["rssi_dbm"]),
                _fmt_int(wifi["freq_mhz"]), _fmt_int(wifi["last_seen_ms"])]
        parts.append((wifi["scan_t_ms"].to_numpy(np.int64), _join(cols)))

    ble = trace.ble
    if len(ble):
        cols = [_fmt_int(ble["t_ms"]), np.full(len(ble), "TYPE_BEACON", dtype=object),
                _fmt_str(ble["uuid"]), _fmt_int(ble["major"]), _fmt_int(ble["minor"]),
                _fmt_int(ble["tx_power_dbm"]), _fmt_int(ble["rssi_dbm"]),
                format_floats(ble["distance_m"].to_numpy()), _fmt_str(ble["mac"]),
                _fmt_int(ble["last_seen_ms"])]
        parts.append((ble["t_ms"].to_numpy(np.int64), _join(cols)))

    wp = trace.waypoints
    if len(wp):
        cols = [_fmt_int(wp["t_ms"]), np.full(len(wp), "TYPE_WAYPOINT", dtype=object),
                format_floats(wp["x_m"].to_numpy()), format_floats(wp["y_m"].to_numpy())]
        parts.append((wp["t_ms"].to_numpy(np.int64) + int(waypoint_delay_ms), _join(cols)))

    if not parts:
        return []
    keys = np.concatenate([k for k, _ in parts])
    lines = np.concatenate([v for _, v in parts])
    order = np.argsort(keys, kind="stable")
    return lines[order].tolist()


def _join(cols: list[np.ndarray]) -> np.ndarray:
    out = cols[0].astype(object)
    for c in cols[1:]:
        out = out + "\t" + c
    return out


def render_trace(trace: Trace, waypoint_delay_ms: int = 800,
                 extra_lines: list[str] | None = None) -> str:
    """The whole file as text, ``\\n``-terminated lines. ``extra_lines`` are appended to the
    records (used to add undocumented record types in tests and the simulator)."""
    head, tail = header_lines(trace.header)
    body = render_records(trace, waypoint_delay_ms)
    if extra_lines:
        body = body + list(extra_lines)
    return "\n".join(head + body + tail) + "\n"


def write_trace(path: str | os.PathLike, trace: Trace, waypoint_delay_ms: int = 800,
                extra_lines: list[str] | None = None) -> Path:
    """Write ``trace`` to ``path``; gzip-compressed (deterministic, mtime 0) if it ends in ``.gz``.

    The file is written to a temporary name beside the target and renamed into place.
    """
    path = Path(path)
    data = render_trace(trace, waypoint_delay_ms, extra_lines).encode("utf-8")
    if path.suffix == ".gz":
        buf = io.BytesIO()
        with gzip.GzipFile(filename="", mode="wb", fileobj=buf, mtime=0, compresslevel=6) as gz:
            gz.write(data)
        data = buf.getvalue()
    from .publish import atomic_write_bytes

    atomic_write_bytes(path, data, overwrite=True)
    return path
