"""The trace format of survey walks and its in-memory form.

A trace is tab-separated text, one record per line: Unix time (ms), a record type, then values
(see ``docs/trace_format.md``). This module is the single description of the record layouts; the
reader, the writer and the simulator all use it.

In memory a parsed trace is a :class:`Trace`: a header and one pandas table per stream, each with
the columns listed in the ``*_COLUMNS`` constants below, sorted by time.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

#: Sensor record types -> stream name used in the store. Calibrated streams carry x, y, z and an
#: accuracy; uncalibrated ones carry x, y, z, the bias the phone estimated per axis, and accuracy.
CALIBRATED_STREAMS: dict[str, str] = {
    "TYPE_ACCELEROMETER": "accelerometer",
    "TYPE_GYROSCOPE": "gyroscope",
    "TYPE_MAGNETIC_FIELD": "magnetic_field",
    "TYPE_ROTATION_VECTOR": "rotation_vector",
}
UNCALIBRATED_STREAMS: dict[str, str] = {
    "TYPE_ACCELEROMETER_UNCALIBRATED": "accelerometer_uncalibrated",
    "TYPE_GYROSCOPE_UNCALIBRATED": "gyroscope_uncalibrated",
    "TYPE_MAGNETIC_FIELD_UNCALIBRATED": "magnetic_field_uncalibrated",
}
SENSOR_STREAMS: dict[str, str] = {**CALIBRATED_STREAMS, **UNCALIBRATED_STREAMS}
STREAM_TO_RECORD: dict[str, str] = {v: k for k, v in SENSOR_STREAMS.items()}
#: Stream names in a fixed order; the store keeps the stream as this category.
STREAM_NAMES: tuple[str, ...] = tuple(SENSOR_STREAMS.values())

#: Largest magnitude of a sensor value (and of an uncalibrated stream's bias) a phone reports,
#: by stream, with its unit: phones saturate near 16 g, 35 rad/s and 5000 uT, and rotation
#: vector components are those of a unit quaternion. A value beyond is a corrupt sample (one
#: accelerometer value of 1e30 made phantom steps): an ``out_of_range`` bad line.
SENSOR_LIMIT_OF_STREAM: dict[str, tuple[float, str]] = {
    "accelerometer": (2000.0, "m/s^2"), "gyroscope": (200.0, "rad/s"),
    "magnetic_field": (10_000.0, "uT"), "rotation_vector": (1.5, "")}


#: How far (ms) a Wi-Fi row's last-seen time may lie after its scan's time: a row is heard
#: before the scan reports it (the ILC traces: never after), and a damaged file gave last-seen
#: times hours after their scan; such a row is an ``out_of_range`` bad line (its age would
#: be negative, and the radio maps weigh rows by age).
MAX_WIFI_SEEN_AFTER_SCAN_MS = 1000
#: A Wi-Fi row last seen longer than this (ms) before its scan has its last-seen time on
#: another clock (0, or Android's ``ScanResult.timestamp``, microseconds since boot): its age
#: is unknown and taken as 0, as for a log without last-seen times, and counted under the
#: rule ``wifi_last_seen_other_clock``. Taken as decades old, every such row was dropped by
#: the maps and the localizer, silently. The ILC rows are at most 32 s old.
MAX_WIFI_AGE_MS = 3_600_000
#: Rules counted in :attr:`ParseReport.dropped` whose rows are kept, mended.
KEPT_ROW_RULES = ("wifi_last_seen_other_clock",)


def n_dropped(counts: dict[str, int]) -> int:
    """Rows a ``dropped`` count (rule -> rows) removed: all but :data:`KEPT_ROW_RULES`'."""
    return int(sum(v for k, v in counts.items() if k not in KEPT_ROW_RULES))

#: How far (ms) outside the sensor samples' time span a walk's scans, beacon rows or
#: waypoints may all lie before :meth:`Trace.clock_mismatch` calls the clocks different.
CLOCK_TOLERANCE_MS = 60_000

#: A record more than this far (ms) from the median time of its walk's records of its type is
#: a ``time_outlier`` bad line: a wrong clock or a stray row. Steps are detected on a uniform
#: time grid over the accelerometer's span, and one accelerometer row at time 0 among a walk's
#: of 2019 asked for 625 GiB; with this rule a stream spans at most twice the bound (a whole
#: stream stamped with another clock is still read, see :meth:`Trace.clock_mismatch`).
MAX_FROM_MEDIAN_TIME_MS = 12 * 3_600_000


def far_from_median_time(t_ms: np.ndarray, group: np.ndarray, n_groups: int, *,
                         per_group: int = 200) -> np.ndarray:
    """Which rows lie more than :data:`MAX_FROM_MEDIAN_TIME_MS` from the median time of their
    group (a walk's records of one type). ``t_ms``: times (ms, ``(n,)``); ``group``: group of
    each row in ``0..n_groups - 1``. Each group's median is taken over an even subsample of
    about ``per_group`` of its rows (all of a smaller group), so the cost stays that of a
    scan and a stray row cannot be a group's only sample. Returns a boolean ``(n,)``."""
    t = np.asarray(t_ms, dtype=np.float64)
    group = np.asarray(group, dtype=np.int64)
    if not len(t):
        return np.zeros(0, dtype=bool)
    index_type = np.int32 if len(t) < 2**31 else np.int64  # int32 modulo: 5x faster
    stride = np.maximum(1, np.bincount(group, minlength=n_groups) // per_group)
    chosen = np.flatnonzero(np.arange(len(t), dtype=index_type)
                            % stride.astype(index_type)[group] == 0)
    g, ts = group[chosen], t[chosen]
    order = np.lexsort((ts, g))
    g, ts = g[order], ts[order]
    n = np.bincount(g, minlength=n_groups)
    first = np.concatenate([[0], np.cumsum(n)[:-1]])
    median = np.full(n_groups, np.nan)
    has = n > 0
    median[has] = ts[first[has] + (n[has] - 1) // 2]
    return np.abs(t - median[group]) > MAX_FROM_MEDIAN_TIME_MS


#: Largest |coordinate| (m) of a waypoint or walk-plan vertex: the map bundle's limit
#: (``localize.bundle.MAX_COORD_M``), so that plans and walks in a projected CRS (a UTM
#: northing is 4,000 km or more) are read; 1e155 m crashed the processing of every walk of
#: the store. (1e6 m before session 50: no walk at a UTM northing could be read.)
WAYPOINT_LIMIT_M = 1e8


def sensor_limit(stream: str) -> tuple[float, str]:
    """(largest plausible |value|, unit) of a stream (``inf`` for a name it does not know)."""
    return SENSOR_LIMIT_OF_STREAM.get(stream.removesuffix("_uncalibrated"), (float("inf"), ""))


#: Number of values after (timestamp, type) for every documented record type.
VALUE_COUNTS: dict[str, int] = {
    **{k: 4 for k in CALIBRATED_STREAMS},
    **{k: 7 for k in UNCALIBRATED_STREAMS},
    "TYPE_WIFI": 5,  # ssid, bssid, rssi dBm, frequency MHz, last-seen ms
    "TYPE_BEACON": 8,  # uuid, major, minor, tx power dBm, rssi dBm, distance m, MAC, time ms
    "TYPE_WAYPOINT": 2,  # x m, y m
}
DOCUMENTED_TYPES: frozenset[str] = frozenset(VALUE_COUNTS)

SENSOR_COLUMNS = ("stream", "t_ms", "x", "y", "z", "bx", "by", "bz", "accuracy")
WIFI_COLUMNS = ("scan_t_ms", "ssid", "bssid", "rssi_dbm", "freq_mhz", "last_seen_ms", "age_ms")
BLE_COLUMNS = ("t_ms", "uuid", "major", "minor", "key", "tx_power_dbm", "rssi_dbm",
               "distance_m", "mac", "last_seen_ms")
WAYPOINT_COLUMNS = ("t_ms", "x_m", "y_m")

SENSOR_DTYPES = {"t_ms": "int64", "x": "float32", "y": "float32", "z": "float32",
                 "bx": "float32", "by": "float32", "bz": "float32", "accuracy": "int8"}
WIFI_DTYPES = {"scan_t_ms": "int64", "rssi_dbm": "int16", "freq_mhz": "int32",
               "last_seen_ms": "int64", "age_ms": "int64"}
BLE_DTYPES = {"t_ms": "int64", "major": "int32", "minor": "int32", "tx_power_dbm": "int16",
              "rssi_dbm": "int16", "distance_m": "float64", "last_seen_ms": "int64"}
WAYPOINT_DTYPES = {"t_ms": "int64", "x_m": "float64", "y_m": "float64"}


@dataclass(frozen=True)
class SensorInfo:
    """One ``#\ttype:N\tname:...`` header line: a sensor the phone declared."""

    type_code: int
    name: str = ""
    vendor: str = ""
    version: str = ""
    resolution: float = float("nan")
    power_ma: float = float("nan")
    maximum_range: float = float("nan")


@dataclass
class TraceHeader:
    """Metadata from the ``#`` lines of a trace. Missing items are ``None``."""

    start_ms: int | None = None
    end_ms: int | None = None
    site_id: str | None = None
    site_name: str | None = None
    floor_id: str | None = None
    floor_name: str | None = None
    brand: str | None = None
    model: str | None = None
    android_version: str | None = None
    api_level: str | None = None
    app_version: str | None = None
    sensors: list[SensorInfo] = field(default_factory=list)
    extra: dict[str, str] = field(default_factory=dict)


def bad_lines_summary(bad: Mapping[str, int], messages: Sequence[str] = ()) -> str:
    """One line on skipped bad lines: ``"N bad line(s) skipped (reason n, ...); first: msg"``
    (build, localize and validate say it so; ingest prints the same counts as a table)."""
    total = int(sum(bad.values()))
    text = f"{total} bad line(s) skipped"
    if bad:
        text += " (" + ", ".join(f"{k} {v}" for k, v in sorted(bad.items())) + ")"
    return text + (f"; first: {messages[0]}" if messages else "")


@dataclass
class ParseReport:
    """What a parse kept, skipped and rejected; every line of the file is in exactly one count.

    ``lines_total == header_lines + blank_lines + sum(records) + sum(skipped) + sum(bad)`` where
    ``records`` counts parsed lines per documented type, ``skipped`` undocumented types
    (per type) and ``bad`` malformed lines (per reason). ``dropped`` counts rows removed after
    parsing by a stated rule (duplicate sensor timestamps, duplicate BSSIDs in a scan), and
    rows kept but mended by one of :data:`KEPT_ROW_RULES`; they are already included in
    ``records``. :meth:`n_dropped` counts those removed. ``messages`` keeps the first few ``file:line: reason``.
    """

    path: str = "<input>"
    lines_total: int = 0
    header_lines: int = 0
    blank_lines: int = 0
    records: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)
    bad: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    messages: list[str] = field(default_factory=list)

    @property
    def bad_total(self) -> int:
        return int(sum(self.bad.values()))

    def n_dropped(self) -> int:
        """Rows removed by a rule (those of :data:`KEPT_ROW_RULES` were kept)."""
        return n_dropped(self.dropped)

    @property
    def skipped_total(self) -> int:
        return int(sum(self.skipped.values()))

    def accounted_lines(self) -> int:
        """Lines covered by the counts; equals ``lines_total`` for a consistent report."""
        return (self.header_lines + self.blank_lines + sum(self.records.values())
                + self.skipped_total + self.bad_total)


@dataclass
class Trace:
    """A parsed survey walk: header plus one time-sorted table per stream.

    Tables (columns and dtypes in the module constants):

    - ``sensors``: long table of the seven sensor streams; ``stream`` names the stream,
      ``x, y, z`` are the values (m/s^2, rad/s, uT, or rotation-vector components), ``bx, by, bz``
      the phone's bias estimate for uncalibrated streams (NaN otherwise), ``accuracy`` Android's
      accuracy flag. Sorted by (stream, t_ms).
    - ``wifi``: one row per (scan, BSSID) with RSSI (dBm), frequency (MHz), last-seen time and
      ``age_ms = scan_t_ms - last_seen_ms`` (0 when over :data:`MAX_WIFI_AGE_MS`: another
      clock). Sorted by (scan_t_ms, bssid).
    - ``ble``: one row per beacon sighting, keyed ``uuid:major:minor``. Sorted by t_ms.
    - ``waypoints``: ground-truth clicks (x east, y north, metres). Sorted by t_ms.
    """

    trace_id: str
    header: TraceHeader
    sensors: pd.DataFrame
    wifi: pd.DataFrame
    ble: pd.DataFrame
    waypoints: pd.DataFrame
    report: ParseReport = field(default_factory=ParseReport)

    @property
    def is_empty(self) -> bool:
        """No sensor sample, waypoint, Wi-Fi or BLE row: an empty file, or not a trace file."""
        return not (len(self.sensors) or len(self.waypoints) or len(self.wifi) or len(self.ble))

    def empty_reason(self) -> str:
        """Why :attr:`is_empty` holds, with the reader's first problem line."""
        r = self.report
        csv = str(r.path or "").lower().endswith(".csv")
        return (f"no sensor sample, waypoint or scan in {r.lines_total} lines ({r.bad_total} "
                "bad): empty, or not a trace file"
                + (f" (first problem: {r.messages[0]})" if r.messages else "")
                + ("; a walk-line sensor CSV is ingested through the walk plan naming it "
                   "(docs/walkline_format.md)" if csv else ""))

    def clock_mismatch(self, tolerance_ms: float = CLOCK_TOLERANCE_MS) -> str | None:
        """Why the streams cannot share one clock, or None: the Wi-Fi scans, BLE rows or
        waypoints of a walk with sensor samples all lie more than ``tolerance_ms`` outside the
        samples' time span (a logger that stamped one stream with another clock, e.g. the
        time since boot). Such a walk's scans meet none of its steps (it has "no fix") and its
        waypoints are compared with the track's ends."""
        if not len(self.sensors):
            return None
        t = self.sensors["t_ms"].to_numpy()
        lo, hi = float(t.min()), float(t.max())
        for what, times in (("Wi-Fi scans", self.wifi["scan_t_ms"]),
                            ("BLE rows", self.ble["t_ms"]),
                            ("waypoints", self.waypoints["t_ms"])):
            v = times.to_numpy(dtype=np.float64)
            if len(v) and not ((v >= lo - tolerance_ms) & (v <= hi + tolerance_ms)).any():
                return (f"its {what} ({v.min():.0f} .. {v.max():.0f} ms) all lie outside the "
                        f"sensor samples' time span ({lo:.0f} .. {hi:.0f} ms): the streams are "
                        "stamped with different clocks")
        return None

    def stream(self, name: str) -> pd.DataFrame:
        """Rows of one sensor stream (e.g. ``"magnetic_field"``), time-sorted."""
        if name not in STREAM_NAMES:
            raise KeyError(f"unknown sensor stream {name!r}; expected one of {STREAM_NAMES}")
        return self.sensors[self.sensors["stream"] == name].reset_index(drop=True)


def empty_table(columns: tuple[str, ...], dtypes: dict[str, str]) -> pd.DataFrame:
    """An empty table with the given columns; string columns get pandas' ``str`` dtype."""
    return pd.DataFrame({c: pd.Series([], dtype=dtypes.get(c, "str")) for c in columns})


def stream_category(values: Iterable[str]) -> pd.Categorical:
    """Stream names as a categorical with the fixed category order :data:`STREAM_NAMES`."""
    return pd.Categorical(values, categories=list(STREAM_NAMES))
