"""Assemble one walk's simulated streams into a :class:`~survey.trace_format.Trace`."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..trace_format import (
    SENSOR_COLUMNS,
    SENSOR_DTYPES,
    WAYPOINT_DTYPES,
    Trace,
    TraceHeader,
    stream_category,
)
from .devices import Device

#: Android accuracy flag written per stream (the real phone writes 2 for the accelerometer).
STREAM_ACCURACY: dict[str, int] = {
    "accelerometer": 2, "gyroscope": 3, "magnetic_field": 3, "rotation_vector": 3,
    "accelerometer_uncalibrated": 3, "gyroscope_uncalibrated": 3,
    "magnetic_field_uncalibrated": 3,
}

#: App version written in the simulated headers.
APP_VERSION = "indoormap-sim-1"


def sensor_table(t_ms: np.ndarray, streams: dict[str, tuple[np.ndarray, np.ndarray | None]]
                 ) -> pd.DataFrame:
    """Long sensor table of :class:`~survey.trace_format.Trace`.

    Parameters
    ----------
    t_ms : numpy.ndarray, shape (n,), int64
        Common timestamps of all streams.
    streams : dict
        Stream name -> ``(values (n, 3), bias (3,) or None)``; ``bias`` for uncalibrated streams.

    Returns
    -------
    pandas.DataFrame
        Columns :data:`~survey.trace_format.SENSOR_COLUMNS`, sorted by (stream, t_ms), values
        stored as float32.
    """
    n = len(t_ms)
    parts = []
    for name, (values, bias) in streams.items():
        v = np.asarray(values, dtype=np.float32).reshape(n, 3)
        b = (np.full((n, 3), np.nan, dtype=np.float32) if bias is None
             else np.broadcast_to(np.asarray(bias, dtype=np.float32), (n, 3)))
        parts.append(pd.DataFrame({
            "stream": stream_category([name] * n),
            "t_ms": np.asarray(t_ms, dtype=np.int64),
            "x": v[:, 0], "y": v[:, 1], "z": v[:, 2],
            "bx": b[:, 0], "by": b[:, 1], "bz": b[:, 2],
            "accuracy": np.full(n, STREAM_ACCURACY[name], dtype=np.int8),
        }))
    df = pd.concat(parts, ignore_index=True)
    df["stream"] = stream_category(df["stream"].astype(str))
    df = df.sort_values(["stream", "t_ms"], kind="stable").reset_index(drop=True)
    return df.astype(SENSOR_DTYPES)[list(SENSOR_COLUMNS)]


def waypoint_table(t_ms: np.ndarray, xy_m: np.ndarray) -> pd.DataFrame:
    """Waypoint table (:data:`~survey.trace_format.WAYPOINT_COLUMNS`), sorted by time."""
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    df = pd.DataFrame({"t_ms": np.asarray(t_ms, dtype=np.int64), "x_m": xy[:, 0],
                       "y_m": xy[:, 1]})
    return df.astype(WAYPOINT_DTYPES).sort_values("t_ms", kind="stable").reset_index(drop=True)


def make_header(start_ms: int, end_ms: int, site_id: str, site_name: str, floor_id: str,
                floor_name: str, device: Device) -> TraceHeader:
    """Trace header like the real logger's."""
    m = device.model
    return TraceHeader(start_ms=int(start_ms), end_ms=int(end_ms), site_id=site_id,
                       site_name=site_name, floor_id=floor_id, floor_name=floor_name,
                       brand=m.brand, model=m.model, android_version=m.android_version,
                       api_level=m.api_level, app_version=APP_VERSION,
                       sensors=[s.info() for s in m.sensors])


def build_trace(trace_id: str, header: TraceHeader, sensors: pd.DataFrame, wifi: pd.DataFrame,
                ble: pd.DataFrame, waypoints: pd.DataFrame) -> Trace:
    """A :class:`~survey.trace_format.Trace` from its parts (Wi-Fi rows kept in file order:
    by scan time, strongest first, as the real logger writes them)."""
    return Trace(trace_id=trace_id, header=header, sensors=sensors, wifi=wifi, ble=ble,
                 waypoints=waypoints)
