"""indoormap's own walk-line format: a GeoJSON walk plan plus one sensor CSV per walk.

For samplers who walk planned lines (see ``docs/walkline_format.md``). A plan is a GeoJSON
FeatureCollection in map metres (x east, y north); each LineString feature is one walk with

- ``walk_id`` (required): the trace id in the store;
- ``sensor_log`` (required): path of the walk's sensor CSV, relative to the plan file;
- either ``start_ms`` and ``end_ms`` (vertices get times in proportion to distance along the
  line, i.e. a steady pace) or ``vertex_times_ms`` (one strictly increasing time per vertex);
- optional ``site_id``, ``site_name``, ``floor_id``, ``floor_name``, ``device_brand``,
  ``device_model``; the collection's own ``properties`` give defaults for every walk.

The sensor CSV has a header row, one row per sample, and the column ``t_ms`` (Unix ms) plus any
of these groups (a group is all-or-nothing): ``acc_x,acc_y,acc_z`` (m/s^2), ``gyro_x..z`` (rad/s),
``mag_x..z`` (uT), ``rot_x..z`` (Android rotation vector), ``acc_uncal_x..z`` with
``acc_bias_x..z``, ``gyro_uncal_x..z`` with ``gyro_bias_x..z``, ``mag_uncal_x..z`` with
``mag_bias_x..z``, and optionally ``accuracy``. The plan's vertices become the walk's waypoints.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv
from numpy.typing import NDArray

from .errors import SurveyFormatError
from .regular_files import read_regular
from .trace_bytes import MAX_TRACE_BYTES, check_not_utf16_or_32
from .trace_format import (
    BLE_COLUMNS,
    BLE_DTYPES,
    MAX_FROM_MEDIAN_TIME_MS,
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
#: Largest walk-plan GeoJSON read (bytes): a plan of thousands of walks is a few MB.
MAX_PLAN_BYTES = 256 * 2**20
#: Times (Unix ms) must be below this; larger values are not times of this format.
MAX_TIME_MS = 2**53
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


@dataclass(frozen=True, eq=False)
class PlanWalk:
    """One walk of a walk plan, its feature checked (:func:`plan_walks`) and its sensor log
    not yet read (:meth:`read`)."""

    walk_id: str
    sensor_log: str  #: as the plan gives it, relative to the plan's folder
    where: str  #: ``plan (feature k)``, for messages
    folder: Path  #: the plan's folder
    props: dict  #: the feature's properties over the collection's defaults
    feature: dict
    xy_m: NDArray[np.float64]  #: vertices (n, 2+) (m)
    times_ms: NDArray[np.float64]  #: vertex times (n,) (Unix ms, whole)

    def read(self, *, strict: bool = False) -> tuple[Trace, str, bytes]:
        """Read the walk's sensor log: ``(trace, source path of the sensor CSV, identity
        bytes)`` (the canonical feature JSON plus the CSV content, what the store hashes to
        detect changes): :meth:`log_bytes`, :meth:`identity` and :meth:`parse`.

        Raises
        ------
        SurveyFormatError
            A missing or malformed sensor CSV (strict mode: also any bad CSV row).
        """
        source, csv_bytes = self.log_bytes()
        return self.parse(source, csv_bytes, strict=strict), source, self.identity(csv_bytes)

    def log_bytes(self) -> tuple[str, bytes]:
        """``(path, content)`` of the walk's sensor CSV, not parsed (``ingest`` hashes a walk
        before it parses it, and skips an unchanged one).

        Raises
        ------
        SurveyFormatError
            The sensor CSV is missing or not a readable regular file.
        """
        log = self.sensor_log
        try:
            csv_path = (self.folder / log).resolve()
            return str(csv_path), read_regular(csv_path, MAX_TRACE_BYTES)  # not a FIFO
        except (OSError, ValueError) as err:  # ValueError: a NUL byte in the path
            raise SurveyFormatError(f"sensor log {log!r} not readable "
                                    f"({getattr(err, 'strerror', None) or err})",
                                    path=self.where, reason="io") from err

    def identity(self, csv_bytes: bytes) -> bytes:
        """What identifies this version of the walk: its feature with the collection's
        defaults it inherits (a change in either is a change of the walk) and its sensor
        CSV's bytes."""
        feature = {**self.feature, "properties": self.props}
        return json.dumps(feature, sort_keys=True).encode() + b"\n" + csv_bytes

    def parse(self, source: str, csv_bytes: bytes, *, strict: bool = False) -> Trace:
        """The walk as a trace from its sensor CSV's bytes (read from ``source``), its
        header from the plan's properties and its waypoints the plan's vertices.

        Raises
        ------
        SurveyFormatError
            A malformed sensor CSV (strict mode: also any bad CSV row).
        """
        check_not_utf16_or_32(csv_bytes, source)
        times, xy = self.times_ms, self.xy_m
        trace = parse_sensor_csv(csv_bytes, reference_ms=float(np.median(times)),
                                 path=source, strict=strict)
        trace.trace_id = self.walk_id
        for prop, attr in _HEADER_PROPS.items():
            if self.props.get(prop) is not None:
                setattr(trace.header, attr, str(self.props[prop]))
        trace.header.start_ms, trace.header.end_ms = int(times[0]), int(times[-1])
        trace.waypoints = pd.DataFrame({"t_ms": times.astype(np.int64), "x_m": xy[:, 0],
                                        "y_m": xy[:, 1]})
        return trace


def read_walk_plan(path: str | os.PathLike, *, strict: bool = False
                   ) -> list[tuple[Trace, str, bytes]]:
    """Read a walk plan and its sensor logs: :func:`plan_walks`, each walk read
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
        geom = (feature.get("geometry") or {}) if isinstance(feature, dict) else None
        if not isinstance(own or {}, dict) or not isinstance(geom, dict):
            raise SurveyFormatError("feature must be an object with object 'properties' and "
                                    "'geometry'", path=where, reason="plan")
        props = {**defaults, **(own or {})}
        if geom.get("type") != "LineString":
            raise SurveyFormatError("walk geometry must be a LineString", path=where,
                                    reason="plan")
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
        walk_id = str(props.get("walk_id") or "").strip()
        log = props.get("sensor_log")
        if not walk_id or not log:
            hint = ("; this looks like the simulator's planned_routes.geojson (the routes its "
                    "walks follow, not a walk plan): ingest the traces in path_data_files/"
                    if walk_id and "start_ms" in props else "")
            raise SurveyFormatError("feature needs properties 'walk_id' and 'sensor_log'"
                                    + hint, path=where, reason="plan")
        if not isinstance(log, str):
            raise SurveyFormatError("'sensor_log' must be a path (a string)", path=where,
                                    reason="plan")
        times = _vertex_times(xy[:, :2], props, where)
        walks.append(PlanWalk(walk_id, log, where, path.parent, props, feature, xy, times))
    if not walks:
        raise SurveyFormatError("walk plan has no features", path=str(path), reason="plan")
    return walks


def identity_sha256(identity: bytes) -> str:
    return hashlib.sha256(identity).hexdigest()


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
        try:
            start, end = float(props["start_ms"]), float(props["end_ms"])
        except (TypeError, ValueError, OverflowError) as err:
            raise SurveyFormatError("start_ms and end_ms must be numbers", path=where,
                                    reason="plan") from err
        if not (0 <= start < MAX_TIME_MS and 0 <= end < MAX_TIME_MS):
            raise SurveyFormatError("start_ms and end_ms must be within [0, 2^53) ms",
                                    path=where, reason="plan")
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


def _numeric(column: pa.ChunkedArray) -> np.ndarray:
    """Float64 values of a CSV column, NaN where a value is missing or not a number (columns
    pyarrow typed as booleans, dates or times hold no numbers)."""
    kind = column.type
    if pa.types.is_integer(kind) or pa.types.is_floating(kind):
        return pc.cast(column, pa.float64(), safe=False).to_numpy(zero_copy_only=False)
    if pa.types.is_string(kind) or pa.types.is_large_string(kind):
        return pd.to_numeric(column.to_pandas(), errors="coerce").to_numpy(dtype=float,
                                                                             na_value=np.nan)
    return np.full(len(column), np.nan)


def _missing(column: pa.ChunkedArray) -> np.ndarray:
    """Where a CSV column has no value (empty or null)."""
    missing = column.is_null().to_numpy(zero_copy_only=False)
    if pa.types.is_string(column.type) or pa.types.is_large_string(column.type):
        missing = missing | (pc.utf8_trim_whitespace(column).to_numpy(zero_copy_only=False)
                             == "")
    return missing


def _row_lines(data: bytes, n_rows: int, skipped: list[int]
               ) -> tuple[np.ndarray, np.ndarray]:
    """1-based line numbers of the CSV rows read and of the rows pyarrow ``skipped`` (given
    as pyarrow numbers them: 1-based among the non-blank lines, the header first). pyarrow
    skips blank lines, so row ``i`` is not always line ``i + 2``. Falls back to ``i + 2`` (and
    pyarrow's numbers) when the lines cannot be matched (a quoted field spanning lines, old
    Mac line ends)."""
    lines = data.split(b"\n")
    filled = np.flatnonzero([bool(line.strip(b"\r")) for line in lines]) + 1
    at = np.asarray(skipped, dtype=np.int64) - 1
    if len(filled) == n_rows + 1 + len(skipped) and (at >= 1).all():
        return np.delete(filled, at)[1:], filled[at]
    return np.arange(n_rows) + 2, at + 1


def parse_sensor_csv(data: bytes, *, reference_ms: float, path: str = "<input>",
                     strict: bool = False) -> Trace:
    """Parse a walk-line sensor CSV into a :class:`Trace` (sensors only). ``reference_ms``:
    the walk's time (Unix ms; the median of its plan's vertex times), which a row more than
    :data:`MAX_FROM_MEDIAN_TIME_MS` from is a ``time_outlier``."""
    report = ParseReport(path=path)
    wrong_width: list[tuple[int | None, int, int]] = []  # (row number, fields, expected)

    def skip_row(row) -> str:  # a row with too few or too many fields is one bad line
        wrong_width.append((row.number, row.actual_columns, row.expected_columns))
        return "skip"

    # Bytes that are not UTF-8 become U+FFFD: pyarrow cannot report a wrong-width row holding
    # them, and a value holding one is then non-numeric, a bad line like any other.
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        data = data.decode("utf-8", errors="replace").encode("utf-8")
    try:
        table = pacsv.read_csv(  # one thread: pyarrow numbers the rows it skips
            io.BytesIO(data), read_options=pacsv.ReadOptions(use_threads=False),
            parse_options=pacsv.ParseOptions(invalid_row_handler=skip_row),
            convert_options=pacsv.ConvertOptions(column_types={}, strings_can_be_null=False))
        names = table.column_names  # decoding a name can fail
    except pa.ArrowInvalid as err:
        raise SurveyFormatError(f"not a readable CSV ({err})", path=path, reason="csv") from err
    if wrong_width and not table.num_rows:
        _, got, want = wrong_width[0]
        raise SurveyFormatError(f"not a readable CSV: no row has the header's {want} fields "
                                f"(the first has {got})", path=path, reason="csv")
    if len(set(names)) != len(names):
        raise SurveyFormatError("sensor log has duplicate column names", path=path, reason="csv")
    columns = set(names)
    if "t_ms" not in columns:
        sep = next((sep for sep in (";", "\t", "|") if len(names) == 1 and sep in names[0]),
                   None)
        said = (f": its header is one column, {names[0][:40]!r}; the log must be "
                f"comma-separated, not {'tab' if sep == chr(9) else repr(sep)}-separated"
                if sep else "")
        raise SurveyFormatError(f"sensor log needs a 't_ms' column{said}", path=path,
                                reason="csv")
    report.lines_total = table.num_rows + 1 + len(wrong_width)
    report.header_lines = 1
    numeric = {c: _numeric(table.column(c)) for c in names}
    t = numeric["t_ms"]
    bad_t = ~np.isfinite(t) | (t < 0)
    parts = []
    row_bad = bad_t.copy()
    implausible = np.zeros(len(t), dtype=bool)
    column_bad: list[tuple[str, NDArray[np.bool_]]] = []  # rows each sensor column makes bad
    for stream, (prefix, bias) in STREAM_COLUMNS.items():
        cols = [f"{prefix}_{a}" for a in _AXES] + ([f"{bias}_{a}" for a in _AXES] if bias else [])
        present = [c for c in cols if c in columns]
        if not present:
            continue
        if len(present) != len(cols):
            raise SurveyFormatError(f"stream {stream} needs columns {cols}, missing "
                                    f"{sorted(set(cols) - set(present))}", path=path,
                                    reason="csv")
        values = np.column_stack([numeric[c] for c in cols])
        # a row that leaves all of a stream's columns empty has no sample of it (streams
        # logged at their own rates, one event per row); one that fills them in part is bad
        absent = np.column_stack([_missing(table.column(c)) for c in cols]).all(axis=1)
        # stored as float32: a value beyond its range would become infinite
        unstorable = ~absent[:, None] & ~(np.abs(values) < _FLOAT32_LIMIT)
        unphysical = ~absent[:, None] & (np.abs(values) > sensor_limit(stream)[0])
        row_bad |= unstorable.any(axis=1)
        implausible |= unphysical.any(axis=1)
        column_bad.extend(zip(cols, (unstorable | unphysical).T))
        parts.append((stream, values, ~absent))
    if not parts:
        raise SurveyFormatError("sensor log has no sensor columns (e.g. acc_x, acc_y, acc_z)",
                                path=path, reason="csv")
    row_bad |= ~np.column_stack([has for _, _, has in parts]).any(axis=1)  # no sample at all
    # An accuracy, when given, is a whole number (a missing one means 3). Out of range: a time
    # beyond 2^53 ms, an accuracy beyond int8.
    acc = numeric.get("accuracy")
    if acc is not None:
        not_whole = ~_missing(table.column("accuracy")) & ~(np.isfinite(acc)
                                                            & (acc == np.round(acc)))
        row_bad |= not_whole
        column_bad.append(("accuracy", not_whole | (np.abs(acc) > 127)))
    out_of_range = ~row_bad & ((t >= MAX_TIME_MS) | implausible)
    if acc is not None:
        out_of_range |= ~row_bad & (np.abs(acc) > 127)
    # a row far in time from the walk's plan: a wrong clock or a stray row, as the trace
    # reader's time_outlier; one row at time 0 made step detection ask for hundreds of GiB
    timed = ~row_bad & ~out_of_range
    time_outlier = timed & (np.abs(t - reference_ms) > MAX_FROM_MEDIAN_TIME_MS)
    if timed.any() and (time_outlier == timed).all():
        raise SurveyFormatError(
            f"every row's t_ms is over {MAX_FROM_MEDIAN_TIME_MS // 3_600_000} h from the walk "
            f"plan's vertex times (median {reference_ms:.0f} ms): the log and the plan are on "
            "different clocks", path=path, reason="clock")
    problems = {"non_numeric": (row_bad, "non-numeric, missing or non-finite value"),
                "out_of_range": (out_of_range, "t_ms beyond 2^53 ms, accuracy beyond 127 or a "
                                               "sensor value no phone reports (e.g. beyond "
                                               "2000 m/s^2)"),
                "time_outlier": (time_outlier, f"t_ms is over "
                                               f"{MAX_FROM_MEDIAN_TIME_MS // 3_600_000} h from "
                                               "the walk's time (a wrong clock or a stray "
                                               "row)")}
    any_bad = row_bad | out_of_range | time_outlier
    column_bad.insert(0, ("t_ms", bad_t | (t >= MAX_TIME_MS) | time_outlier))

    def _bad_column(i: int) -> str:
        """The first column that makes row ``i`` bad, with its value, for its message."""
        for c, bad_rows in column_bad:
            if bad_rows[i]:
                v = table.column(c)[i].as_py()
                return f"column {c} ({'empty' if v in (None, '') else repr(v)})"
        return "no sensor column filled"

    if any_bad.any() or wrong_width:
        line, skipped_line = _row_lines(data, table.num_rows,
                                        [n or 0 for n, _, _ in wrong_width])
        reason = np.select([row_bad, out_of_range], ["non_numeric", "out_of_range"],
                           "time_outlier")
        # the first 20 bad lines (for the messages) are among the first 20 of either kind
        bad = sorted([(int(line[i]), f"{problems[reason[i]][1]}: {_bad_column(i)}",
                       str(reason[i])) for i in np.flatnonzero(any_bad)[:20]]
                     + [(int(at), f"{got} fields, the header has {want}", "field_count")
                        for at, (_, got, want) in zip(skipped_line[:20], wrong_width)])
        if strict:
            at, message, reason = bad[0]
            raise SurveyFormatError(message, path=path, line=at, reason=reason)
        for reason, (mask, _) in problems.items():
            if mask.any():
                report.bad[reason] = int(mask.sum())
        if wrong_width:
            report.bad["field_count"] = len(wrong_width)
        report.messages = [f"{path}:{at}: {message}" for at, message, _ in bad[:20]]
    good = ~any_bad
    if not good.any():  # nothing to store: a walk without sensors, refused as an empty trace
        why = (f"none of its {table.num_rows + len(wrong_width)} rows is usable ("
               + ", ".join(f"{k} {v}" for k, v in report.bad.items())
               + f"; the first: {report.messages[0]})" if report.messages else "no rows")
        raise SurveyFormatError(f"sensor log has no sample: {why}", path=path, reason="empty")
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
    # Each CSV row is a "line" holding several streams: count lines, not stream rows.
    report.records = {"SENSOR_ROW": int(good.sum())}
    return Trace(trace_id=Path(path).stem, header=TraceHeader(), sensors=sensors,
                 wifi=empty_table(WIFI_COLUMNS, WIFI_DTYPES),
                 ble=empty_table(BLE_COLUMNS, BLE_DTYPES),
                 waypoints=pd.DataFrame({"t_ms": pd.Series([], dtype="int64"),
                                         "x_m": pd.Series([], dtype="float64"),
                                         "y_m": pd.Series([], dtype="float64")}),
                 report=report)
