"""indoormap's own walk-line format: a GeoJSON walk plan plus one sensor CSV per walk.

For samplers who walk planned lines (see ``docs/walkline_format.md``). A plan is a GeoJSON
FeatureCollection in map metres (x east, y north); each LineString feature is one walk with

- ``walk_id`` (required): the trace id in the store;
- ``sensor_log`` (required): path of the walk's sensor CSV, relative to the plan file;
- ``wifi_log``, ``ble_log`` (optional): paths of its Wi-Fi and BLE logs;
- either ``start_ms`` and ``end_ms`` (vertices get times in proportion to distance along the
  line, i.e. a steady pace) or ``vertex_times_ms`` (one strictly increasing time per vertex);
- optional ``site_id``, ``site_name``, ``floor_id``, ``floor_name``, ``device_brand``,
  ``device_model``; the collection's own ``properties`` give defaults for every walk.

A feature with no geometry is a walk without ground truth (no waypoints; ``start_ms`` and
``end_ms`` optional): localized from a radio fix or a given start, never mapped or scored.

The sensor CSV has a header row, one row per sample, and the column ``t_ms`` (Unix ms) plus any
of these groups (a group is all-or-nothing): ``acc_x,acc_y,acc_z`` (m/s^2), ``gyro_x..z`` (rad/s),
``mag_x..z`` (uT), ``rot_x..z`` (Android rotation vector), ``acc_uncal_x..z`` with
``acc_bias_x..z``, ``gyro_uncal_x..z`` with ``gyro_bias_x..z``, ``mag_uncal_x..z`` with
``mag_bias_x..z``, and optionally ``accuracy``. The plan's vertices become the walk's waypoints.

A walk may also name a Wi-Fi and a BLE log (``wifi_log``, ``ble_log``): read by
:mod:`survey.walkline_radio`. The CSV rows of every log are read and checked by
:mod:`survey.walkline_csv`.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from .errors import SurveyFormatError
from .regular_files import read_regular
from .trace_bytes import MAX_TRACE_BYTES, check_not_utf16_or_32
from .trace_format import (
    BLE_COLUMNS,
    BLE_DTYPES,
    STREAM_NAMES,
    WAYPOINT_LIMIT_M,
    WIFI_COLUMNS,
    WIFI_DTYPES,
    ParseReport,
    Trace,
    TraceHeader,
    empty_table,
    sensor_limit,
)
from .walkline_csv import MAX_TIME_MS, RowCheck, good_rows, read_log_csv, time_check

#: CSV column prefix per stream: (value prefix, bias prefix or None).
STREAM_COLUMNS: dict[str, tuple[str, str | None]] = {
    "accelerometer": ("acc", None),
    "gyroscope": ("gyro", None),
    "magnetic_field": ("mag", None),
    "rotation_vector": ("rot", None),
    "accelerometer_uncalibrated": ("acc_uncal", "acc_bias"),
    "gyroscope_uncalibrated": ("gyro_uncal", "gyro_bias"),
    "magnetic_field_uncalibrated": ("mag_uncal", "mag_bias"),
}
_AXES = ("x", "y", "z")
#: ``Trace.header.extra`` key and value of a walk whose waypoint times are not clicks but its
#: plan's ``start_ms``..``end_ms`` spread at a steady pace: errors scored at them include
#: the walker's changes of pace (``localize`` and ``evaluate`` say so).
WAYPOINT_TIMES, PACED = "waypoint_times", "steady pace"
#: Largest walk-plan GeoJSON read (bytes): a plan of thousands of walks is a few MB.
MAX_PLAN_BYTES = 256 * 2**20
# Finite float64 values at or beyond this become infinite as float32 (round to nearest even).
_FLOAT32_LIMIT = 2.0**128 - 2.0**103
_HEADER_PROPS = {"site_id": "site_id", "site_name": "site_name", "floor_id": "floor_id",
                 "floor_name": "floor_name", "device_brand": "brand", "device_model": "model"}


def _plan_json(path: Path) -> object:
    """A plan file's JSON; raises OSError, UnicodeDecodeError, ValueError (not JSON) or
    RecursionError (deep nesting) as :data:`_PLAN_READ_ERRORS`."""
    return json.loads(read_regular(path, MAX_PLAN_BYTES).decode("utf-8"))


#: What reading a plan's JSON (:func:`_plan_json`) raises for a file that is none.
_PLAN_READ_ERRORS = (OSError, UnicodeDecodeError, ValueError, RecursionError)


def is_walk_plan(path: str | os.PathLike) -> bool:
    """True for a ``*.geojson`` FeatureCollection whose features name a ``sensor_log``
    (other GeoJSON, such as floor plans or a simulator's planned routes, is not a walk plan)."""
    path = Path(path)
    if not path.name.endswith(".geojson"):
        return False
    try:
        return _is_walk_plan_data(_plan_json(path))
    except _PLAN_READ_ERRORS:
        return False


def _is_walk_plan_data(data: object) -> bool:
    """Whether a plan file's JSON is a walk plan (:func:`is_walk_plan`)."""
    feats = data.get("features") if isinstance(data, dict) else None
    return isinstance(feats, list) and bool(feats) and all(
        isinstance(f, dict) and isinstance(f.get("properties"), dict)
        and "sensor_log" in f["properties"] for f in feats)


def plan_walk_names(path: str | os.PathLike) -> set[str]:
    """The names a walk plan's walks go by, as :func:`read_walk_plan` reads them: each
    feature's ``walk_id`` (its trace id) and its sensor log's file name (the file it
    resolves to), with and without ``.csv``; empty for a file that is no walk plan
    (:func:`is_walk_plan`; what the reader refuses is said when it reads the plan)."""
    path = Path(path)
    try:
        data = _plan_json(path)
    except _PLAN_READ_ERRORS:
        return set()
    if not _is_walk_plan_data(data) or not isinstance(data.get("properties") or {}, dict):
        return set()
    defaults = data.get("properties") or {}
    names: set[str] = set()
    for f in data["features"]:
        props = {**defaults, **f["properties"]}
        walk_id = str(props.get("walk_id") or "").strip()
        if walk_id:
            names.add(walk_id)
        if isinstance(props.get("sensor_log"), str):
            try:
                log = (path.parent / props["sensor_log"]).resolve().name
            except (OSError, ValueError):  # a loop of links, a NUL byte
                continue
            names |= {log, log.removesuffix(".csv")}
    return names


#: The logs a walk names, by property (the radio logs optional): what messages call them.
LOGS = {"sensor_log": "sensor log", "wifi_log": "Wi-Fi log", "ble_log": "BLE log"}


@dataclass(frozen=True)
class WalkLogs:
    """A plan walk's log files as read, not parsed (:meth:`PlanWalk.log_bytes`): per log
    property (``sensor_log``, and ``wifi_log``/``ble_log`` when the plan names them), the
    file's resolved path and its bytes."""

    files: dict[str, tuple[str, bytes]]

    @property
    def source(self) -> str:
        """The sensor CSV's path: the walk's source in the store and in messages."""
        return self.files["sensor_log"][0]


@dataclass(frozen=True, eq=False)
class PlanWalk:
    """One walk of a walk plan, its feature checked (:func:`plan_walks`) and its logs not
    yet read (:meth:`read`)."""

    walk_id: str
    sensor_log: str  #: as the plan gives it, relative to the plan's folder
    where: str  #: ``plan (feature k)``, for messages
    folder: Path  #: the plan's folder
    props: dict  #: the feature's properties over the collection's defaults
    feature: dict
    xy_m: NDArray[np.float64]  #: vertices (n, 2+) (m)
    times_ms: NDArray[np.float64]  #: vertex times (n,) (Unix ms, whole)

    def read(self, *, strict: bool = False) -> tuple[Trace, str, bytes]:
        """Read the walk's logs: ``(trace, source path of the sensor CSV, identity bytes)``
        (the canonical feature JSON plus the logs' content, what the store hashes to detect
        changes): :meth:`log_bytes`, :meth:`identity` and :meth:`parse`.

        Raises
        ------
        SurveyFormatError
            A missing or malformed log (strict mode: also any bad CSV row).
        """
        logs = self.log_bytes()
        return self.parse(logs, strict=strict), logs.source, self.identity(logs)

    def log_bytes(self) -> WalkLogs:
        """The walk's logs as read, not parsed (``ingest`` hashes a walk before it parses
        it, and skips an unchanged one).

        Raises
        ------
        SurveyFormatError
            A log is missing or not a readable regular file.
        """
        files = {}
        for prop, what in LOGS.items():
            log = self.props.get(prop)
            if log is None:
                continue
            try:
                csv_path = (self.folder / log).resolve()
                files[prop] = str(csv_path), read_regular(csv_path, MAX_TRACE_BYTES)  # no FIFO
            except (OSError, ValueError) as err:  # ValueError: a NUL byte in the path
                raise SurveyFormatError(f"{what} {log!r} not readable "
                                        f"({getattr(err, 'strerror', None) or err})",
                                        path=self.where, reason="io") from err
        return WalkLogs(files)

    def identity(self, logs: WalkLogs) -> bytes:
        """What identifies this version of the walk: its feature with the collection's
        defaults it inherits (a change in either is a change of the walk) and its logs'
        bytes (the sensor CSV's, then the radio logs' the feature names)."""
        feature = {**self.feature, "properties": self.props}
        return b"\n".join([json.dumps(feature, sort_keys=True).encode(),
                           *(logs.files[p][1] for p in LOGS if p in logs.files)])

    def parse(self, logs: WalkLogs, *, strict: bool = False) -> Trace:
        """The walk as a trace from its logs' bytes: its sensors from the sensor CSV, its
        Wi-Fi scans and BLE rows from the radio logs the plan names (else none), its header
        from the plan's properties and its waypoints the plan's vertices.

        Raises
        ------
        SurveyFormatError
            A malformed log (strict mode: also any bad CSV row).
        """
        # the radio logs' reader brings the trace reader (numba): imported when a walk is parsed
        from .walkline_radio import parse_ble_csv, parse_wifi_csv

        for path, data in logs.files.values():
            check_not_utf16_or_32(data, path)
        times, xy = self.times_ms, self.xy_m
        source, csv_bytes = logs.files["sensor_log"]
        trace = parse_sensor_csv(csv_bytes, path=source, strict=strict,
                                 reference_ms=float(np.median(times)) if len(times) else None)
        # a walk without times of its own is at its sensor log's
        reference_ms = float(np.median(times)) if len(times) else \
            float(trace.sensors["t_ms"].median())
        for prop, table, parse in (("wifi_log", "wifi", parse_wifi_csv),
                                   ("ble_log", "ble", parse_ble_csv)):
            if prop in logs.files:
                path, data = logs.files[prop]
                setattr(trace, table, parse(data, reference_ms=reference_ms,
                                            report=trace.report, path=path, strict=strict))
        trace.trace_id = self.walk_id
        for prop, attr in _HEADER_PROPS.items():
            if self.props.get(prop) is not None:
                setattr(trace.header, attr, str(self.props[prop]))
        if len(times):
            trace.header.start_ms, trace.header.end_ms = int(times[0]), int(times[-1])
        if len(xy):
            trace.waypoints = pd.DataFrame({"t_ms": times.astype(np.int64), "x_m": xy[:, 0],
                                            "y_m": xy[:, 1]})
            if self.props.get("vertex_times_ms") is None:  # times from start_ms and end_ms
                trace.header.extra[WAYPOINT_TIMES] = PACED
        return trace


def read_walk_plan(path: str | os.PathLike, *, strict: bool = False
                   ) -> list[tuple[Trace, str, bytes]]:
    """Read a walk plan and its walks' logs: :func:`plan_walks`, each walk read
    (:meth:`PlanWalk.read`).

    Returns
    -------
    list of (Trace, source path of the sensor CSV, identity bytes)
        One per walk; the identity bytes (the canonical feature JSON plus the CSV content)
        are what the store hashes to detect changes.

    Raises
    ------
    SurveyFormatError
        Invalid JSON, a feature without the required properties, vertex times out of order,
        a missing or malformed sensor CSV (strict mode: also any bad CSV row).
    """
    return [walk.read(strict=strict) for walk in plan_walks(path)]


def plan_walks(path: str | os.PathLike) -> list[PlanWalk]:
    """A walk plan's walks, every feature checked, their sensor logs not read.

    Raises
    ------
    SurveyFormatError
        Invalid JSON, a feature without the required properties, vertex times out of order.
    """
    path = Path(path)
    try:
        plan = _plan_json(path)
    except _PLAN_READ_ERRORS as err:
        raise SurveyFormatError(f"not a readable GeoJSON walk plan ({err})", path=str(path),
                                reason="plan") from err
    if not isinstance(plan, dict) or plan.get("type") != "FeatureCollection":
        raise SurveyFormatError("walk plan must be a GeoJSON FeatureCollection", path=str(path),
                                reason="plan")
    defaults = plan.get("properties") or {}
    features = plan.get("features") or []
    if not isinstance(defaults, dict) or not isinstance(features, list):
        raise SurveyFormatError("walk plan 'properties' must be an object and 'features' a list",
                                path=str(path), reason="plan")
    walks = []
    for k, feature in enumerate(features):
        where = f"{path} (feature {k})"
        own = feature.get("properties") if isinstance(feature, dict) else None
        if not isinstance(feature, dict) or not isinstance(own or {}, dict) \
                or "geometry" not in feature:  # a missing key is a typo, not "no line"
            raise SurveyFormatError("feature must be an object with object 'properties' and "
                                    "'geometry' (null for a walk without ground truth)",
                                    path=where, reason="plan")
        props = {**defaults, **(own or {})}
        geom = feature["geometry"]
        if geom is None:  # no ground truth: a walk to localize, not to map
            walks.append(_untruthed_walk(props, where, path.parent, feature))
            continue
        if not isinstance(geom, dict) or geom.get("type") != "LineString":
            raise SurveyFormatError("walk geometry must be a LineString (or null: a walk "
                                    "without ground truth)", path=where, reason="plan")
        coords = geom.get("coordinates")
        numbers = isinstance(coords, list) and all(
            isinstance(pt, list) and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                         for v in pt) for pt in coords)
        try:  # JSON numbers only: "27.8" or true are not coordinates
            xy = np.asarray(coords, dtype=float) if numbers else np.empty(0)
        except (TypeError, ValueError, OverflowError):  # ragged, huge integers
            xy = np.empty(0)
        if xy.ndim != 2 or xy.shape[0] < 2 or xy.shape[1] < 2 or not np.isfinite(xy).all():
            raise SurveyFormatError("LineString needs at least two finite [x, y] vertices "
                                    "(JSON numbers)", path=where, reason="plan")
        if np.abs(xy[:, :2]).max() > WAYPOINT_LIMIT_M:
            raise SurveyFormatError(f"a vertex lies beyond +-{WAYPOINT_LIMIT_M:g} m (the plan "
                                    "is in map metres)", path=where, reason="plan")
        walk_id, log = _walk_logs(props, where)
        times = _vertex_times(xy[:, :2], props, where)
        walks.append(PlanWalk(walk_id, log, where, path.parent, props, feature, xy, times))
    if not walks:
        raise SurveyFormatError("walk plan has no features", path=str(path), reason="plan")
    return walks


def _walk_logs(props: dict, where: str) -> tuple[str, str]:
    """A feature's ``walk_id`` and ``sensor_log``, its log properties checked to be paths."""
    walk_id = str(props.get("walk_id") or "").strip()
    log = props.get("sensor_log")
    if not walk_id or not log:
        hint = ("; this looks like the simulator's planned_routes.geojson (the routes its "
                "walks follow, not a walk plan): ingest the traces in path_data_files/"
                if walk_id and "start_ms" in props else "")
        raise SurveyFormatError("feature needs properties 'walk_id' and 'sensor_log'" + hint,
                                path=where, reason="plan")
    for prop in LOGS:
        if props.get(prop) is not None and not isinstance(props[prop], str):
            raise SurveyFormatError(f"{prop!r} must be a path (a string)", path=where,
                                    reason="plan")
    return walk_id, log


def _untruthed_walk(props: dict, where: str, folder: Path, feature: dict) -> PlanWalk:
    """A feature without geometry: a walk with no waypoints (nothing to map it with or score
    it against; ``localize`` starts it from a radio fix or ``--start``). Its ``start_ms`` and
    ``end_ms``, when given, are its time; otherwise its sensor log's median time is."""
    walk_id, log = _walk_logs(props, where)
    times = np.empty(0)
    if (props.get("start_ms") is None) != (props.get("end_ms") is None):
        raise SurveyFormatError("a walk without geometry gives both start_ms and end_ms, or "
                                "neither (its sensor log's times are then its time)",
                                path=where, reason="plan")
    if props.get("start_ms") is not None:
        times = np.round(np.array(_start_end_ms(props, where)))
        if not times[0] <= times[1]:
            raise SurveyFormatError("start_ms and end_ms must be within [0, 2^53) ms, the "
                                    "start not after the end", path=where, reason="plan")
    return PlanWalk(walk_id, log, where, folder, props, feature, np.empty((0, 2)), times)


def sensor_log_walk(path: str | os.PathLike) -> PlanWalk:
    """A sensor CSV given alone (``indoormap localize BUNDLE walk.csv``) as a walk without
    ground truth: its id the file's name without ``.csv``, its Wi-Fi and BLE logs the files
    beside it named as :mod:`survey.walkline_writer` names them (``walk.wifi.csv``,
    ``walk.ble.csv``) when they exist, no floor (the floor model or a one-floor map decides)."""
    path = Path(path)
    stem = path.name[:-len(".csv")] if path.name.lower().endswith(".csv") else path.name
    props = {"walk_id": stem, "sensor_log": path.name}
    for prop, suffix in (("wifi_log", ".wifi.csv"), ("ble_log", ".ble.csv")):
        if (path.parent / f"{stem}{suffix}").is_file():
            props[prop] = f"{stem}{suffix}"
    feature = {"type": "Feature", "geometry": None, "properties": props}
    return PlanWalk(stem, path.name, str(path), path.parent, props, feature, np.empty((0, 2)),
                    np.empty(0))


def identity_sha256(identity: bytes) -> str:
    return hashlib.sha256(identity).hexdigest()


def _start_end_ms(props: dict, where: str) -> tuple[float, float]:
    """A feature's ``start_ms`` and ``end_ms`` (Unix ms), each a number within [0, 2^53)."""
    try:
        start, end = float(props["start_ms"]), float(props["end_ms"])
    except (TypeError, ValueError, OverflowError) as err:
        raise SurveyFormatError("start_ms and end_ms must be numbers", path=where,
                                reason="plan") from err
    if not (0 <= start < MAX_TIME_MS and 0 <= end < MAX_TIME_MS):
        raise SurveyFormatError("start_ms and end_ms must be within [0, 2^53) ms", path=where,
                                reason="plan")
    return start, end


def _vertex_times(xy: np.ndarray, props: dict, where: str) -> np.ndarray:
    if props.get("vertex_times_ms") is not None:
        try:
            times = np.round(np.asarray(props["vertex_times_ms"], dtype=np.float64))
        except (TypeError, ValueError, OverflowError) as err:
            raise SurveyFormatError("vertex_times_ms must be numbers", path=where,
                                    reason="plan") from err
        if times.shape != (len(xy),):
            raise SurveyFormatError(f"vertex_times_ms has {times.size} values for {len(xy)} "
                                    "vertices", path=where, reason="plan")
    elif props.get("start_ms") is not None and props.get("end_ms") is not None:
        start, end = _start_end_ms(props, where)
        # Huge coordinates overflow to an infinite length or time, refused below.
        with np.errstate(over="ignore", invalid="ignore"):
            dist = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
            if not dist[-1] > 0 or not np.isfinite(dist[-1]):
                raise SurveyFormatError("walk line has zero or non-finite length", path=where,
                                        reason="plan")
            times = np.round(start + (end - start) * dist / dist[-1])
    else:
        raise SurveyFormatError("feature needs 'start_ms' and 'end_ms' or 'vertex_times_ms'",
                                path=where, reason="plan")
    if (not np.isfinite(times).all() or times.min() < 0 or times.max() >= MAX_TIME_MS
            or np.any(np.diff(times) <= 0)):
        raise SurveyFormatError("vertex times must be within [0, 2^53) ms and strictly "
                                "increasing (after rounding to whole ms)", path=where,
                                reason="plan")
    return times


#: Unix ms of 2000-01-01 and 2100-01-01: where a log's times lie when they are Unix ms.
UNIX_MS_SPAN = (946_684_800_000.0, 4_102_444_800_000.0)


def unix_ms_unit(t: NDArray[np.float64]) -> str:
    """The unit a log's times (positive, finite) look like when their median is no Unix ms
    of this century but would be in seconds, microseconds or nanoseconds; else empty (Unix
    ms, or times since the phone booted, which no unit explains)."""
    if not len(t):
        return ""
    median, (lo, hi) = float(np.median(t)), UNIX_MS_SPAN
    for unit, to_ms in (("seconds", 1e3), ("microseconds", 1e-3), ("nanoseconds", 1e-6)):
        if not lo <= median <= hi and lo <= median * to_ms <= hi:
            return unit
    return ""


def parse_sensor_csv(data: bytes, *, reference_ms: float | None, path: str = "<input>",
                     strict: bool = False) -> Trace:
    """Parse a walk-line sensor CSV into a :class:`Trace` (sensors only). ``reference_ms``:
    the walk's time (Unix ms; the median of its plan's vertex times; None: the median of the
    log's own times, as the trace reader measures), which a row more than
    :data:`~survey.trace_format.MAX_FROM_MEDIAN_TIME_MS` from is a ``time_outlier``."""
    report = ParseReport(path=path)
    log = read_log_csv(data, path, "sensor log", ("t_ms",))
    columns = log.columns
    t = log.numbers("t_ms")
    bad_t = ~np.isfinite(t) | (t < 0)
    if reference_ms is None:  # no plan's times to compare with: the log's own, in ms?
        unit = unix_ms_unit(t[np.isfinite(t) & (t > 0)])
        if unit:
            raise SurveyFormatError(f"the log's t_ms (median {np.median(t[np.isfinite(t)]):.6g})"
                                    f" look like {unit}, not Unix milliseconds", path=path,
                                    reason="clock")
        timed = ~bad_t & (t < MAX_TIME_MS)
        reference_ms = float(np.median(t[timed])) if timed.any() else 0.0
    parts = []
    row_bad = bad_t.copy()
    implausible = np.zeros(len(t), dtype=bool)
    unstorable_by_column: list[tuple[str, NDArray[np.bool_]]] = []
    unphysical_by_column: list[tuple[str, NDArray[np.bool_]]] = []
    for stream, (prefix, bias) in STREAM_COLUMNS.items():
        cols = [f"{prefix}_{a}" for a in _AXES] + ([f"{bias}_{a}" for a in _AXES] if bias else [])
        present = [c for c in cols if c in columns]
        if not present:
            continue
        if len(present) != len(cols):
            raise SurveyFormatError(f"stream {stream} needs columns {cols}, missing "
                                    f"{sorted(set(cols) - set(present))}", path=path,
                                    reason="csv")
        values = np.column_stack([log.numbers(c) for c in cols])
        # a row that leaves all of a stream's columns empty has no sample of it (streams
        # logged at their own rates, one event per row); one that fills them in part is bad
        absent = np.column_stack([log.missing(c) for c in cols]).all(axis=1)
        # stored as float32: a value beyond its range would become infinite
        unstorable = ~absent[:, None] & ~(np.abs(values) < _FLOAT32_LIMIT)
        unphysical = ~absent[:, None] & (np.abs(values) > sensor_limit(stream)[0])
        row_bad |= unstorable.any(axis=1)
        implausible |= unphysical.any(axis=1)
        unstorable_by_column.extend(zip(cols, unstorable.T))
        unphysical_by_column.extend(zip(cols, unphysical.T))
        parts.append((stream, values, ~absent))
    if not parts:
        raise SurveyFormatError("sensor log has no sensor columns (e.g. acc_x, acc_y, acc_z)",
                                path=path, reason="csv")
    no_sample = ~np.column_stack([has for _, _, has in parts]).any(axis=1)
    # An accuracy, when given, is a whole number (a missing one means 3). Out of range: a time
    # beyond 2^53 ms, an accuracy beyond int8.
    acc = log.numbers("accuracy") if "accuracy" in columns else None
    accuracy_bad = []
    if acc is not None:
        not_whole = ~log.missing("accuracy") & ~(np.isfinite(acc) & (acc == np.round(acc)))
        accuracy_bad = [("accuracy", not_whole | (np.abs(acc) > 127))]
        implausible |= np.abs(acc) > 127
        row_bad |= not_whole
    row_bad |= no_sample
    beyond_t = t >= MAX_TIME_MS
    checks = [RowCheck("non_numeric", "non-numeric, missing or non-finite value", row_bad,
                       [("t_ms", bad_t), *unstorable_by_column, *accuracy_bad],
                       otherwise="no sensor column filled"),
              RowCheck("out_of_range", "t_ms beyond 2^53 ms, accuracy beyond 127 or a sensor "
                       "value no phone reports (e.g. beyond 2000 m/s^2)",
                       ~row_bad & (beyond_t | implausible),
                       [("t_ms", beyond_t), *unphysical_by_column, *accuracy_bad])]
    checks.append(time_check(log, t, ~row_bad & ~checks[1].rows, reference_ms))
    good = good_rows(log, checks, report, strict=strict, row_name="SENSOR_ROW", unit="sample")
    accuracy_all = np.nan_to_num(acc if acc is not None else np.full(len(t), 3.0),
                                 nan=3.0)
    frames = []
    for stream, values, has in parts:
        rows = good & has
        v, t_ms, accuracy = values[rows], t[rows].astype(np.int64), \
            accuracy_all[rows].astype(np.int8)
        order = np.argsort(t_ms, kind="stable")
        keep = np.ones(len(order), dtype=bool)
        keep[1:] = t_ms[order][1:] != t_ms[order][:-1]
        if not keep.all():
            report.dropped["duplicate_timestamp"] = report.dropped.get(
                "duplicate_timestamp", 0) + int((~keep).sum())
        order = order[keep]
        frames.append(pd.DataFrame({
            "stream": stream, "t_ms": t_ms[order],
            "x": v[order, 0], "y": v[order, 1], "z": v[order, 2],
            "bx": v[order, 3] if v.shape[1] > 3 else np.nan,
            "by": v[order, 4] if v.shape[1] > 3 else np.nan,
            "bz": v[order, 5] if v.shape[1] > 3 else np.nan,
            "accuracy": accuracy[order]}))
    sensors = pd.concat(frames, ignore_index=True)
    sensors["stream"] = pd.Categorical(sensors["stream"], categories=list(STREAM_NAMES))
    sensors = sensors.astype({"x": "float32", "y": "float32", "z": "float32", "bx": "float32",
                              "by": "float32", "bz": "float32"})
    sensors = sensors.sort_values(["stream", "t_ms"], kind="stable").reset_index(drop=True)
    return Trace(trace_id=Path(path).stem, header=TraceHeader(), sensors=sensors,
                 wifi=empty_table(WIFI_COLUMNS, WIFI_DTYPES),
                 ble=empty_table(BLE_COLUMNS, BLE_DTYPES),
                 waypoints=pd.DataFrame({"t_ms": pd.Series([], dtype="int64"),
                                         "x_m": pd.Series([], dtype="float64"),
                                         "y_m": pd.Series([], dtype="float64")}),
                 report=report)
