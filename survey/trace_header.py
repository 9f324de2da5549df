"""Parsing the ``#`` header lines of a trace into a :class:`~survey.trace_format.TraceHeader`.

Header lines hold tab-separated ``key:value`` pairs. A line whose first key is ``type`` declares a
sensor. Unknown keys are kept in ``TraceHeader.extra``; malformed values never fail a read.

A key that says which walk a trace is (site, floor, start and end time, phone, app: the
``_HEADER_KEYS`` and ``_TIME_KEYS``) given again with a different value fails the read in every
mode: it is what two traces joined into one file look like (``cat a.txt.gz b.txt.gz``), whose
rows cannot be told apart, so the second walk's header would silently relabel the first walk's
data. The same value again is fine. Other keys are not compared: sensor lines (a phone may list
two sensors of one type), unknown keys, and a ``startTime``/``endTime`` that is not a time (it is
kept as text in ``TraceHeader.extra``, never as the walk's time, so it relabels nothing).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from .errors import SurveyFormatError
from .trace_format import SensorInfo, TraceHeader

_HEADER_KEYS = {
    "SiteID": "site_id", "SiteName": "site_name", "FloorId": "floor_id",
    "FloorName": "floor_name", "Brand": "brand", "Model": "model",
    "AndroidName": "android_version", "APILevel": "api_level", "VersionName": "app_version",
}
_TIME_KEYS = {"startTime": "start_ms", "endTime": "end_ms"}


def parse_header(lines: Iterable[bytes], *, path: str | None = None,
                 line_numbers: Sequence[int] | None = None) -> TraceHeader:
    """Header from the raw ``#`` lines (bytes, without newline) of one trace.

    Raises :class:`SurveyFormatError` (reason ``header_conflict``, naming ``path`` and the line,
    from ``line_numbers``: one per line) for a walk key given again with a different value.
    """
    header = TraceHeader()
    seen: dict[str, tuple[str | int, str, int]] = {}  # key -> (compared, value, line index)
    for i, raw in enumerate(lines):
        text = raw.decode("utf-8", errors="replace")
        pairs = [f.split(":", 1) for f in text[1:].split("\t") if ":" in f]
        if not pairs:
            continue
        keys = [k.strip() for k, _ in pairs]
        if keys[0] == "type":
            header.sensors.append(_sensor_info(dict((k.strip(), v.strip()) for k, v in pairs)))
            continue
        for key, value in zip(keys, (v.strip() for _, v in pairs)):
            # Unix ms, 1-16 ASCII digits like record timestamps (int() would also take huge,
            # signed, '_'-grouped or non-ASCII digits that do not fit the store)
            ms = int(value) if key in _TIME_KEYS and _is_time(value) else None
            if key in _HEADER_KEYS or ms is not None:
                compared = value if ms is None else ms
                first = seen.setdefault(key, (compared, value, i))
                if first[0] != compared:
                    _conflict(key, value, first[1:], i, path, line_numbers)
            if ms is not None:
                setattr(header, _TIME_KEYS[key], ms)
            elif key in _HEADER_KEYS:
                setattr(header, _HEADER_KEYS[key], value)
            else:
                header.extra[key] = value
    return header


def _is_time(value: str) -> bool:
    return value.isascii() and value.isdigit() and len(value) <= 16


def _conflict(key: str, value: str, first: tuple[str, int], i: int, path: str | None,
              line_numbers: Sequence[int] | None) -> None:
    def line(j: int) -> int | None:
        return None if line_numbers is None else int(line_numbers[j])

    where = "on the same line" if first[1] == i else (
        f"on line {line(first[1])}" if line_numbers is not None else "earlier")
    raise SurveyFormatError(
        f"header {key} is {_short(value)!r} here but {_short(first[0])!r} {where}: two traces "
        "joined into one file? Which rows belong to which walk cannot be told, so none are read",
        path=path, line=line(i), reason="header_conflict")


def _short(value: str) -> str:
    return value if len(value) <= 60 else value[:57] + "..."


def _sensor_info(values: dict[str, str]) -> SensorInfo:
    def num(key: str) -> float:
        try:
            return float(values.get(key, "nan"))
        except ValueError:
            return float("nan")

    try:
        code = int(values.get("type", "-1"))
    except ValueError:
        code = -1
    return SensorInfo(type_code=code, name=values.get("name", ""),
                      vendor=values.get("vendor", ""), version=values.get("version", ""),
                      resolution=num("resolution"), power_ma=num("power"),
                      maximum_range=num("maximumRange"))
