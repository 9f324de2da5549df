"""Small hand-built traces for tests (no simulator needed)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from survey.trace_format import SensorInfo, Trace, TraceHeader, stream_category


def small_trace(n: int = 50, seed: int = 0, trace_id: str = "walk0001") -> Trace:
    """A small, valid trace with every documented record type (values as float32)."""
    rng = np.random.default_rng(seed)
    t0 = 1_600_000_000_000
    t = t0 + 20 * np.arange(n, dtype=np.int64)
    frames = []
    for stream in ("accelerometer", "gyroscope", "magnetic_field", "rotation_vector",
                   "accelerometer_uncalibrated", "gyroscope_uncalibrated",
                   "magnetic_field_uncalibrated"):
        xyz = rng.normal(0, 0.3 if stream == "rotation_vector" else 10, (n, 3)).astype(np.float32)
        unc = stream.endswith("uncalibrated")
        bias = rng.normal(0, 5, (n, 3)).astype(np.float32) if unc else np.full((n, 3), np.nan,
                                                                                np.float32)
        frames.append(pd.DataFrame({"stream": stream, "t_ms": t, "x": xyz[:, 0], "y": xyz[:, 1],
                                    "z": xyz[:, 2], "bx": bias[:, 0], "by": bias[:, 1],
                                    "bz": bias[:, 2], "accuracy": np.int8(3)}))
    sensors = pd.concat(frames, ignore_index=True)
    sensors["stream"] = stream_category(sensors["stream"])
    sensors = sensors.astype({"accuracy": "int8"})
    scans = t0 + 1000 * np.arange(max(1, n // 50) + 1)
    wifi = pd.DataFrame({
        "scan_t_ms": np.repeat(scans, 3),
        "ssid": np.tile(["ap-one", "", "caf\u00e9 wifi"], len(scans)),
        "bssid": np.tile(["00:11:22:33:44:55", "00:11:22:33:44:66", "aa:bb:cc:dd:ee:ff"],
                         len(scans)),
        "rssi_dbm": rng.integers(-95, -30, 3 * len(scans)).astype(np.int16),
        "freq_mhz": np.tile([2412, 5180, 2437], len(scans)).astype(np.int32),
    })
    wifi["last_seen_ms"] = wifi["scan_t_ms"] - rng.integers(0, 5000, len(wifi))
    wifi["age_ms"] = wifi["scan_t_ms"] - wifi["last_seen_ms"]
    wifi = wifi.astype({"ssid": "str", "bssid": "str"})
    ble = pd.DataFrame({
        "t_ms": t[::10], "uuid": "0a1b2c3d-4e5f-4a6b-8c7d-9e0f1a2b3c4d",
        "major": np.int32(10), "minor": np.arange(len(t[::10]), dtype=np.int32),
        "tx_power_dbm": np.int16(-59), "rssi_dbm": np.int16(-70),
        "distance_m": np.round(rng.uniform(0.5, 20, len(t[::10])), 3),
        "mac": "e0:78:a3:3d:b5:d6", "last_seen_ms": t[::10]})
    ble["key"] = ble["uuid"] + ":10:" + ble["minor"].astype(str)
    ble = ble[["t_ms", "uuid", "major", "minor", "key", "tx_power_dbm", "rssi_dbm",
               "distance_m", "mac", "last_seen_ms"]].astype({"uuid": "str", "key": "str",
                                                             "mac": "str"})
    wp = pd.DataFrame({"t_ms": [t[0], t[n // 2], t[-1]], "x_m": [1.5, 10.25, 20.0],
                       "y_m": [2.0, 2.5, 8.75]})
    header = TraceHeader(start_ms=int(t[0]) - 5, end_ms=int(t[-1]) + 5, site_id="site_a",
                         site_name="Test site", floor_id="floor_a1", floor_name="F1",
                         brand="ACME", model="P1", android_version="12", api_level="31",
                         app_version="v1",
                         sensors=[SensorInfo(1, "Acc", "V", "1", 0.002, 0.2, 39.0)])
    return Trace(trace_id=trace_id, header=header, sensors=sensors, wifi=wifi, ble=ble,
                 waypoints=wp)
