"""Write walks in indoormap's walk-line format (``docs/walkline_format.md``): a GeoJSON walk
plan whose vertices are the walks' waypoints, and per walk a sensor CSV (each stream's
samples on rows of their own, as phone loggers write them) and, when the walk has any, a
Wi-Fi and a BLE log.

For converting traces (``indoormap simulate`` writes the trace format) and for tests that
read the same walks in both formats. Floats are written with 9 significant digits, so
float32 sensor values survive a round trip exactly.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from localize.names import file_stem

from .publish import atomic_directory
from .trace_format import Trace
from .trace_writer import format_floats
from .walkline import STREAM_COLUMNS

_AXES = ("x", "y", "z")
#: The radio logs' columns, as the store's tables hold them (the scan time is ``t_ms``).
WIFI_LOG_COLUMNS = ("t_ms", "bssid", "rssi_dbm", "freq_mhz", "ssid", "last_seen_ms")
BLE_LOG_COLUMNS = ("t_ms", "uuid", "major", "minor", "rssi_dbm", "tx_power_dbm",
                   "distance_m", "mac", "last_seen_ms")


def sensor_csv(trace: Trace) -> bytes:
    """The walk's sensor CSV: ``t_ms``, every stream's columns (a stream the walk lacks has
    none) and ``accuracy``; one row per stream sample, rows in time order (streams in
    :data:`~survey.walkline.STREAM_COLUMNS` order at equal times)."""
    frames = []
    columns = ["t_ms"]
    for stream, (prefix, bias) in STREAM_COLUMNS.items():
        rows = trace.sensors[trace.sensors["stream"] == stream]
        if not len(rows):
            continue
        names = {f"{prefix}_{a}": a for a in _AXES}
        if bias:
            names |= {f"{bias}_{a}": f"b{a}" for a in _AXES}
        columns += list(names)
        frames.append(pd.DataFrame({"t_ms": rows["t_ms"].to_numpy(),
                                    **{c: _floats(rows[src]) for c, src in names.items()},
                                    "accuracy": rows["accuracy"].to_numpy()}))
    table = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=columns)
    table = table.sort_values("t_ms", kind="stable")
    return table.reindex(columns=[*columns, "accuracy"]).to_csv(index=False).encode()


def _floats(values: pd.Series) -> np.ndarray:
    """Values as the trace writer writes them (float32 exact), empty for NaN."""
    v = values.to_numpy(dtype=np.float64)
    return np.where(np.isnan(v), "", format_floats(v)).astype(object)


def wifi_csv(trace: Trace) -> bytes:
    """The walk's Wi-Fi log (:data:`WIFI_LOG_COLUMNS`), one row per access point and scan."""
    rows = trace.wifi.rename(columns={"scan_t_ms": "t_ms"})
    return rows.reindex(columns=list(WIFI_LOG_COLUMNS)).to_csv(index=False).encode()


def ble_csv(trace: Trace) -> bytes:
    """The walk's BLE log (:data:`BLE_LOG_COLUMNS`), one row per sighting."""
    rows = trace.ble.assign(distance_m=_floats(trace.ble["distance_m"]))
    return rows.reindex(columns=list(BLE_LOG_COLUMNS)).to_csv(index=False).encode()


def walk_feature(trace: Trace, logs: dict[str, str]) -> dict:
    """The walk's plan feature: a LineString through its waypoints (m) at their times (a
    walk without waypoints: no geometry, its header's start and end times), its header's
    site, floor and phone, and its ``logs`` (property -> path, relative to the plan)."""
    wp = trace.waypoints
    if len(wp) == 1:
        raise ValueError(f"walk {trace.trace_id!r} has 1 waypoint; a walk-line walk has none "
                         "or two or more")
    h = trace.header
    header = {"site_id": h.site_id, "site_name": h.site_name, "floor_id": h.floor_id,
              "floor_name": h.floor_name, "device_brand": h.brand, "device_model": h.model}
    if len(wp):
        geometry = {"type": "LineString",
                    "coordinates": wp[["x_m", "y_m"]].to_numpy(np.float64).tolist()}
        times = {"vertex_times_ms": wp["t_ms"].to_numpy(np.int64).tolist()}
    else:
        geometry = None
        times = {"start_ms": h.start_ms, "end_ms": h.end_ms} \
            if h.start_ms is not None and h.end_ms is not None else {}
    return {"type": "Feature", "geometry": geometry,
            "properties": {"walk_id": trace.trace_id, **logs, **times,
                           **{k: v for k, v in header.items() if v is not None}}}


def write_walk_plan(folder: str | os.PathLike, traces: Sequence[Trace], *,
                    plan_name: str = "plan.geojson", overwrite: bool = False) -> Path:
    """Write ``traces`` as one walk plan, ``folder/plan_name``, with their logs in
    ``folder/logs/`` (``<trace id>.csv``, ``<trace id>.wifi.csv``, ``<trace id>.ble.csv``, the
    id made a safe file name by :func:`localize.names.file_stem`);
    the folder is published atomically. Returns the plan's path.

    Raises
    ------
    ValueError
        A walk with one waypoint (a plan's walk is a line through them, or has no line), or
        two walks of one trace id.
    survey.errors.PublishError
        ``folder`` exists and not ``overwrite``.
    """
    ids = [t.trace_id for t in traces]
    if len(set(ids)) != len(ids):
        raise ValueError("two walks share a trace id; a plan's walk ids are unique")
    with atomic_directory(folder, overwrite=overwrite) as tmp:
        (tmp / "logs").mkdir()
        features = []
        for trace in traces:
            files = {"sensor_log": (".csv", sensor_csv(trace))}
            if len(trace.wifi):
                files["wifi_log"] = (".wifi.csv", wifi_csv(trace))
            if len(trace.ble):
                files["ble_log"] = (".ble.csv", ble_csv(trace))
            logs = {}
            for prop, (suffix, data) in files.items():
                logs[prop] = f"logs/{file_stem(trace.trace_id)}{suffix}"
                (tmp / logs[prop]).write_bytes(data)
            features.append(walk_feature(trace, logs))
        plan = {"type": "FeatureCollection", "features": features}
        (tmp / plan_name).write_text(json.dumps(plan, indent=1) + "\n")
    return Path(folder) / plan_name
