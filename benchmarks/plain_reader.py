"""The baseline reader for ``benchmarks/ingest.py``: a plain line-by-line Python parser.

It is what one writes first: open (gunzip) the file as text, loop over lines, split on tabs,
convert the values and append tuples per record type, then sort each stream by time. It keeps the
same information as indoormap's reader (all documented types, bias columns, header pairs) so the
two do the same job.
"""

from __future__ import annotations

import gzip

SENSOR = {"TYPE_ACCELEROMETER", "TYPE_GYROSCOPE", "TYPE_MAGNETIC_FIELD", "TYPE_ROTATION_VECTOR",
          "TYPE_ACCELEROMETER_UNCALIBRATED", "TYPE_GYROSCOPE_UNCALIBRATED",
          "TYPE_MAGNETIC_FIELD_UNCALIBRATED"}


def read_plain(path: str) -> dict:
    opener = gzip.open if path.endswith(".gz") else open
    header: dict[str, str] = {}
    streams: dict[str, list] = {k: [] for k in SENSOR}
    wifi, ble, waypoints = [], [], []
    skipped: dict[str, int] = {}
    with opener(path, "rt", encoding="utf-8") as fh:
        for line in fh:
            line = line.rstrip("\n")
            if not line:
                continue
            if line.startswith("#"):
                for item in line[1:].split("\t"):
                    if ":" in item:
                        k, v = item.split(":", 1)
                        header[k] = v
                continue
            parts = line.split("\t")
            kind = parts[1]
            if kind in SENSOR:
                streams[kind].append((int(parts[0]), *map(float, parts[2:-1]), int(parts[-1])))
            elif kind == "TYPE_WIFI":
                wifi.append((int(parts[0]), parts[2], parts[3].lower(), int(parts[4]),
                             int(parts[5]), int(parts[6])))
            elif kind == "TYPE_BEACON":
                ble.append((int(parts[0]), parts[2], int(parts[3]), int(parts[4]), int(parts[5]),
                            int(parts[6]), float(parts[7]), parts[8], int(parts[9])))
            elif kind == "TYPE_WAYPOINT":
                waypoints.append((int(parts[0]), float(parts[2]), float(parts[3])))
            else:
                skipped[kind] = skipped.get(kind, 0) + 1
    for rows in (*streams.values(), wifi, ble, waypoints):
        rows.sort(key=lambda r: r[0])
    return {"header": header, "streams": streams, "wifi": wifi, "ble": ble,
            "waypoints": waypoints, "skipped": skipped}
