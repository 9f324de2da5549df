"""Parsing the ``#`` header lines of a trace into a :class:`~survey.trace_format.TraceHeader`.

Header lines hold tab-separated ``key:value`` pairs. A line whose first key is ``type`` declares a
sensor. Unknown keys are kept in ``TraceHeader.extra``; malformed values never fail a read.
"""

from __future__ import annotations

from collections.abc import Iterable

from .trace_format import SensorInfo, TraceHeader

_HEADER_KEYS = {
    "SiteID": "site_id", "SiteName": "site_name", "FloorId": "floor_id",
    "FloorName": "floor_name", "Brand": "brand", "Model": "model",
    "AndroidName": "android_version", "APILevel": "api_level", "VersionName": "app_version",
}


def parse_header(lines: Iterable[bytes]) -> TraceHeader:
    """Header from the raw ``#`` lines (bytes, without newline) of one trace."""
    header = TraceHeader()
    for raw in lines:
        text = raw.decode("utf-8", errors="replace")
        pairs = [f.split(":", 1) for f in text[1:].split("\t") if ":" in f]
        if not pairs:
            continue
        keys = [k.strip() for k, _ in pairs]
        values = dict((k.strip(), v.strip()) for k, v in pairs)
        if keys[0] == "type":
            header.sensors.append(_sensor_info(values))
            continue
        for key, value in values.items():
            if key in ("startTime", "endTime"):
                # Unix ms, 1-16 ASCII digits like record timestamps (int() would also take
                # huge, signed, '_'-grouped or non-ASCII digits that do not fit the store)
                if not (value.isascii() and value.isdigit() and len(value) <= 16):
                    header.extra[key] = value
                    continue
                ms = int(value)
                if key == "startTime":
                    header.start_ms = ms
                else:
                    header.end_ms = ms
            elif key in _HEADER_KEYS:
                setattr(header, _HEADER_KEYS[key], value)
            else:
                header.extra[key] = value
    return header


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
