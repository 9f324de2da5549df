"""The walk-line format's CSV logs (sensor, Wi-Fi and BLE logs) read into tables, and their
rows checked: one reader and one bad-row report for every kind of log
(``docs/walkline_format.md``).

A log is comma-separated with a header row. A row with more or fewer fields than the header
is a bad line (``field_count``), as is a row a kind's checks refuse (non-numeric or
missing values, values out of range, a time far from the walk's); lenient parsing skips and
counts them with their ``file:line``, strict parsing raises at the first.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv
from numpy.typing import NDArray

from .errors import SurveyFormatError
from .trace_format import MAX_FROM_MEDIAN_TIME_MS, ParseReport

#: Times (Unix ms) must be below this; larger values are not times of this format.
MAX_TIME_MS = 2**53
_HOURS = MAX_FROM_MEDIAN_TIME_MS // 3_600_000


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


@dataclass
class LogTable:
    """One CSV log read: its rows (``table``, every column as pyarrow typed it) and the rows
    of the wrong width, skipped (``wrong_width``: pyarrow's row number, fields, expected)."""

    path: str
    what: str  #: "sensor log", "Wi-Fi log", "BLE log": for messages
    data: bytes  #: the bytes read, non-UTF-8 bytes replaced
    table: pa.Table
    wrong_width: list[tuple[int | None, int, int]]
    _cache: dict[tuple[str, str], np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def columns(self) -> set[str]:
        return set(self.table.column_names)

    @property
    def n_rows(self) -> int:
        """Rows read (of the header's width)."""
        return self.table.num_rows

    def numbers(self, name: str) -> NDArray[np.float64]:
        """Column ``name`` as float64 (n_rows,), NaN where empty or not a number (everywhere
        when the log has no such column)."""
        key = ("numbers", name)
        if key not in self._cache:
            self._cache[key] = (_numeric(self.table.column(name)) if name in self.columns
                                else np.full(self.n_rows, np.nan))
        return self._cache[key]

    def missing(self, name: str) -> NDArray[np.bool_]:
        """Where column ``name`` is empty (n_rows,; everywhere when the log has none)."""
        key = ("missing", name)
        if key not in self._cache:
            self._cache[key] = (_missing(self.table.column(name)) if name in self.columns
                                else np.ones(self.n_rows, dtype=bool))
        return self._cache[key]

    def texts(self, name: str) -> pa.Array:
        """Column ``name`` as one pyarrow string array, white space trimmed, empty where
        there is no value (n_rows,; everywhere when the log has no such column)."""
        if name not in self.columns:
            return pa.array([""] * self.n_rows, type=pa.string())
        column = self.table.column(name).combine_chunks().cast(pa.string())
        return pc.utf8_trim_whitespace(pc.fill_null(column, ""))

    def value(self, name: str, row: int) -> str:
        """Row ``row``'s value of ``name``, for a message."""
        v = self.table.column(name)[row].as_py()
        return "empty" if v in (None, "") else repr(v)


def read_log_csv(data: bytes, path: str, what: str, required: tuple[str, ...],
                 text_columns: tuple[str, ...] = ()) -> LogTable:
    """Read a CSV log's rows; the header must name every ``required`` column. The
    ``text_columns`` are read as text (an SSID ``007`` stays ``007``), the others as pyarrow
    infers them.

    Raises
    ------
    SurveyFormatError
        Not a readable CSV (no row of the header's width, duplicate column names) or a
        required column missing (reason ``csv``).
    """
    wrong_width: list[tuple[int | None, int, int]] = []

    def skip_row(row) -> str:  # a row with too few or too many fields is one bad line
        wrong_width.append((row.number, row.actual_columns, row.expected_columns))
        return "skip"

    # Bytes that are not UTF-8 become U+FFFD: pyarrow cannot report a wrong-width row holding
    # them, and a value holding one is then not a number, a bad line like any other.
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        data = data.decode("utf-8", errors="replace").encode("utf-8")
    try:
        table = pacsv.read_csv(  # one thread: pyarrow numbers the rows it skips
            io.BytesIO(data), read_options=pacsv.ReadOptions(use_threads=False),
            parse_options=pacsv.ParseOptions(invalid_row_handler=skip_row),
            convert_options=pacsv.ConvertOptions(
                column_types={c: pa.string() for c in text_columns},
                strings_can_be_null=False))
        names = table.column_names  # decoding a name can fail
    except pa.ArrowInvalid as err:
        raise SurveyFormatError(f"not a readable CSV ({err})", path=path, reason="csv") from err
    if wrong_width and not table.num_rows:
        _, got, want = wrong_width[0]
        raise SurveyFormatError(f"not a readable CSV: no row has the header's {want} fields "
                                f"(the first has {got})", path=path, reason="csv")
    if len(set(names)) != len(names):
        raise SurveyFormatError(f"{what} has duplicate column names", path=path, reason="csv")
    lacking = [c for c in required if c not in names]
    if lacking:
        sep = next((sep for sep in (";", "\t", "|") if len(names) == 1 and sep in names[0]),
                   None)
        said = (f": its header is one column, {names[0][:40]!r}; the log must be "
                f"comma-separated, not {'tab' if sep == chr(9) else repr(sep)}-separated"
                if sep else "")
        need = (f"a {lacking[0]!r} column" if len(lacking) == 1
                else "columns " + ", ".join(repr(c) for c in lacking))
        raise SurveyFormatError(f"{what} needs {need}{said}", path=path, reason="csv")
    return LogTable(path, what, data, table, wrong_width)


@dataclass
class RowCheck:
    """Rows one check refuses, as one bad-line ``reason``: ``rows`` (n_rows,) and, per
    column, the rows it makes bad (``columns``, for the message naming the first; a row no
    column names is said to be ``otherwise``)."""

    reason: str
    description: str
    rows: NDArray[np.bool_]
    columns: list[tuple[str, NDArray[np.bool_]]]
    otherwise: str = ""


#: Ratio of a log's times to its plan's (power of ten) -> how it reads and what it suggests.
_TIME_UNITS = {-3: ("a thousandth of", "the log in seconds, or the plan in microseconds"),
               3: ("a thousand times", "the log in microseconds, or the plan in seconds"),
               6: ("a million times", "the log in nanoseconds")}


def _time_unit(t_ms: NDArray[np.float64], reference_ms: float) -> tuple[str, str] | None:
    """How a log's times ``t_ms`` compare with the plan's time ``reference_ms`` when they are
    in another unit (their median a thousandth, a thousand or a million times it, within
    25 %), else None."""
    if not reference_ms > 0:
        return None
    ratio = np.median(t_ms) / reference_ms
    if not ratio > 0:
        return None
    power = int(np.round(np.log10(ratio)))
    return _TIME_UNITS.get(power) if abs(ratio / 10.0 ** power - 1) <= 0.25 else None


#: What a walk's time is, as the messages say it.
_WALK_TIME = "the median of its plan's vertex times, or of its sensor log's when it has none"


def time_check(log: LogTable, t_ms: NDArray[np.float64], usable: NDArray[np.bool_],
               reference_ms: float) -> RowCheck:
    """The ``time_outlier`` rows among the ``usable`` ones: ``t_ms`` more than
    :data:`MAX_FROM_MEDIAN_TIME_MS` from the walk's time ``reference_ms`` (Unix ms; the
    median of its plan's vertex times, or of its sensor log's for a walk without them), a
    wrong clock or a stray row, as the trace reader's (one row at time 0 made step detection
    ask for hundreds of GiB).

    Raises
    ------
    SurveyFormatError
        Every usable row is such a row: the log and the plan are on different clocks, or in
        different units (the log's times a thousandth, a thousand or a million times the
        plan's, named; nanoseconds are beyond 2^53 and not usable) (reason ``clock``).
    """
    outlier = usable & (np.abs(t_ms - reference_ms) > MAX_FROM_MEDIAN_TIME_MS)
    timed = np.isfinite(t_ms)  # with the rows beyond 2^53 ms (nanoseconds)
    unit = _time_unit(t_ms[timed], reference_ms) if timed.any() else None
    if unit is not None and not (usable & ~outlier).any():
        raise SurveyFormatError(
            f"the log's t_ms (median {np.median(t_ms[timed]):.6g}) are {unit[0]} the walk's "
            f"time ({reference_ms:.0f} ms, {_WALK_TIME}): {unit[1]}? Both are Unix "
            "milliseconds", path=log.path, reason="clock")
    if usable.any() and (outlier == usable).all():
        raise SurveyFormatError(
            f"every row's t_ms is over {_HOURS} h from the walk's time ({reference_ms:.0f} ms, "
            f"{_WALK_TIME}): the log is on another clock", path=log.path, reason="clock")
    return RowCheck("time_outlier", f"t_ms is over {_HOURS} h from the walk's time (a wrong "
                    "clock or a stray row)", outlier, [("t_ms", outlier)])


def good_rows(log: LogTable, checks: list[RowCheck], report: ParseReport, *,
              strict: bool, row_name: str, empty_ok: bool = False, unit: str = "usable row"
              ) -> NDArray[np.bool_]:
    """The rows no check refuses (n_rows,); the others, and the rows of the wrong width, are
    counted in ``report`` by reason (a row refused by several checks counts under the first)
    with the first 20 as ``file:line: reason: column (value)`` messages. ``row_name`` is the
    record name the good rows are counted under; ``unit`` what a log without one lacks.

    Raises
    ------
    SurveyFormatError
        ``strict`` and a bad row (naming its line and reason); or no usable row (reason
        ``empty``), unless the log has no row at all and ``empty_ok``.
    """
    report.lines_total += log.n_rows + 1 + len(log.wrong_width)
    report.header_lines += 1
    reason = np.full(log.n_rows, -1)
    for k, check in reversed(list(enumerate(checks))):  # the first check wins
        reason[check.rows] = k
    bad_rows = np.flatnonzero(reason >= 0)
    if len(bad_rows) or log.wrong_width:
        line, skipped_line = _row_lines(log.data, log.n_rows,
                                        [n or 0 for n, _, _ in log.wrong_width])

        def why(i: int) -> str:
            check = checks[reason[i]]
            column = next((c for c, rows in check.columns if rows[i]), None)
            said = (f"column {column} ({log.value(column, i)})" if column
                    else check.otherwise)
            return f"{check.description}: {said}" if said else check.description

        # the first 20 bad lines (for the messages) are among the first 20 of either kind
        bad = sorted([(int(line[i]), why(i), checks[reason[i]].reason) for i in bad_rows[:20]]
                     + [(int(at), f"{got} fields, the header has {want}", "field_count")
                        for at, (_, got, want) in zip(skipped_line[:20], log.wrong_width)])
        if strict:
            at, message, name = bad[0]
            raise SurveyFormatError(message, path=log.path, line=at, reason=name)
        for k, check in enumerate(checks):
            if (n := int((reason == k).sum())):
                report.bad[check.reason] = report.bad.get(check.reason, 0) + n
        if log.wrong_width:
            report.bad["field_count"] = report.bad.get("field_count", 0) + len(log.wrong_width)
        report.messages += [f"{log.path}:{at}: {message}" for at, message, _ in bad[:20]]
    good = reason < 0
    n_all = log.n_rows + len(log.wrong_width)
    if not good.any() and not (empty_ok and not n_all):
        counts = ", ".join(f"{k} {int((reason == i).sum())}" for i, k in
                           enumerate(c.reason for c in checks) if (reason == i).any())
        if log.wrong_width:
            counts = ", ".join(filter(None, [counts, f"field_count {len(log.wrong_width)}"]))
        first = next((m for m in report.messages if m.startswith(f"{log.path}:")), None)
        why_none = (f"none of its {n_all} rows is usable ({counts}; the first: {first})"
                    if n_all else "no rows")
        raise SurveyFormatError(f"{log.what} has no {unit}: {why_none}", path=log.path,
                                reason="empty")
    report.records[row_name] = report.records.get(row_name, 0) + int(good.sum())
    return good
