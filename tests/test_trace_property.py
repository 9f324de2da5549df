"""Property: render random records of every type to the trace format, parse, get them back."""

from __future__ import annotations

import numpy as np
import pandas as pd
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from survey.trace_format import (
    STREAM_NAMES,
    Trace,
    TraceHeader,
    empty_table,
    stream_category,
    BLE_COLUMNS,
    BLE_DTYPES,
)
from survey.trace_format import MAX_FROM_MEDIAN_TIME_MS, SENSOR_LIMIT_OF_STREAM
from survey.trace_reader import parse_trace_bytes
from survey.trace_writer import render_trace

T_MAX_MS = 10**15


@st.composite
def walk_times(draw) -> st.SearchStrategy[int]:
    """Times (ms) of one walk: within 12 h of a base anywhere in the format's range (a record
    farther from the walk's others of its type is a time_outlier bad line,
    tests/test_trace_time_outliers.py)."""
    base = draw(st.integers(0, T_MAX_MS - MAX_FROM_MEDIAN_TIME_MS))
    return st.integers(base, base + MAX_FROM_MEDIAN_TIME_MS)


text = st.text(st.characters(blacklist_categories=("Cs", "Cc")), max_size=12)
mac = st.binary(min_size=6, max_size=6).map(lambda b: ":".join(f"{x:02x}" for x in b))


@st.composite
def traces(draw):
    t_ms = draw(walk_times())
    frames = []
    for stream in draw(st.lists(st.sampled_from(STREAM_NAMES), unique=True, max_size=7)):
        ts = sorted(draw(st.lists(t_ms, min_size=1, max_size=8, unique=True)))
        n = len(ts)
        # any float32 a phone's sensor can report (beyond its limit a value is a bad line)
        limit = SENSOR_LIMIT_OF_STREAM[stream.removesuffix("_uncalibrated")][0]
        value = st.floats(-limit, limit, width=32, allow_nan=False, allow_infinity=False)
        vals = [draw(st.lists(value, min_size=n, max_size=n)) for _ in range(3)]
        unc = stream.endswith("uncalibrated")
        bias = [draw(st.lists(value, min_size=n, max_size=n)) if unc else [np.nan] * n
                for _ in range(3)]
        frames.append(pd.DataFrame({
            "stream": stream, "t_ms": ts, "x": vals[0], "y": vals[1], "z": vals[2],
            "bx": bias[0], "by": bias[1], "bz": bias[2],
            "accuracy": draw(st.lists(st.integers(-1, 3), min_size=n, max_size=n))}))
    if frames:
        sensors = pd.concat(frames, ignore_index=True)
    else:
        sensors = pd.DataFrame({c: [] for c in ("stream", "t_ms", "x", "y", "z", "bx", "by",
                                                  "bz", "accuracy")})
    sensors["stream"] = stream_category(sensors["stream"])
    sensors = sensors.astype({"t_ms": "int64", "x": "float32", "y": "float32", "z": "float32",
                              "bx": "float32", "by": "float32", "bz": "float32",
                              "accuracy": "int8"})
    sensors = sensors.sort_values(["stream", "t_ms"], kind="stable").reset_index(drop=True)

    rows = []
    for scan in sorted(draw(st.lists(t_ms, max_size=3, unique=True))):
        for bssid in draw(st.lists(mac, min_size=1, max_size=4, unique=True)):
            seen = scan - draw(st.integers(0, 60_000))
            rows.append({"scan_t_ms": scan, "ssid": draw(text), "bssid": bssid,
                         "rssi_dbm": draw(st.integers(-127, -1)),  # 0 dBm: "no reading"
                         "freq_mhz": draw(st.sampled_from([2412, 2437, 5180, 5745])),
                         "last_seen_ms": seen, "age_ms": scan - seen})
    wifi = pd.DataFrame(rows, columns=["scan_t_ms", "ssid", "bssid", "rssi_dbm", "freq_mhz",
                                       "last_seen_ms", "age_ms"])
    wifi = wifi.astype({"scan_t_ms": "int64", "ssid": "str", "bssid": "str", "rssi_dbm": "int16",
                        "freq_mhz": "int32", "last_seen_ms": "int64", "age_ms": "int64"})
    wifi = wifi.sort_values(["scan_t_ms", "bssid"], kind="stable").reset_index(drop=True)

    brow = []
    for t in draw(st.lists(t_ms, max_size=4)):
        uuid = draw(st.uuids()).hex
        major, minor = draw(st.integers(0, 65535)), draw(st.integers(0, 65535))
        brow.append({"t_ms": t, "uuid": uuid, "major": major, "minor": minor,
                     "key": f"{uuid}:{major}:{minor}", "tx_power_dbm": draw(st.integers(-100, 0)),
                     "rssi_dbm": draw(st.integers(-127, -1)),  # 0 dBm: "no reading"
                     "distance_m": draw(st.floats(0, 1e4, allow_nan=False)), "mac": draw(mac),
                     "last_seen_ms": t})
    ble = (pd.DataFrame(brow, columns=list(BLE_COLUMNS)).astype(BLE_DTYPES)
           .astype({"uuid": "str", "key": "str", "mac": "str"})
           if brow else empty_table(BLE_COLUMNS, BLE_DTYPES))
    ble = ble.sort_values("t_ms", kind="stable").reset_index(drop=True)

    wts = sorted(draw(st.lists(t_ms, max_size=4)))
    wp = pd.DataFrame({"t_ms": pd.Series(wts, dtype="int64"),
                       "x_m": pd.Series([draw(st.floats(-1e3, 1e3)) for _ in wts],
                                        dtype="float64").astype("float32").astype("float64"),
                       "y_m": pd.Series([draw(st.floats(-1e3, 1e3)) for _ in wts],
                                        dtype="float64").astype("float32").astype("float64")})
    return Trace("walk", TraceHeader(site_id="s", floor_name="F1"), sensors, wifi, ble, wp)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(traces())
def test_render_parse_round_trip(trace):
    got = parse_trace_bytes(render_trace(trace).encode("utf-8"), path="walk.txt")
    assert got.report.bad == {}, got.report.messages
    assert got.report.accounted_lines() == got.report.lines_total
    pd.testing.assert_frame_equal(got.sensors, trace.sensors)
    pd.testing.assert_frame_equal(got.wifi, trace.wifi)
    # a beacon or waypoint row that repeats an earlier one in every value is dropped, counted
    ble = trace.ble.drop_duplicates(ignore_index=True)
    waypoints = trace.waypoints.drop_duplicates(ignore_index=True)
    repeats = {"duplicate_beacon": len(trace.ble) - len(ble),
               "duplicate_waypoint": len(trace.waypoints) - len(waypoints)}
    assert {k: got.report.dropped.get(k, 0) for k in repeats} == repeats
    pd.testing.assert_frame_equal(got.ble, ble)
    pd.testing.assert_frame_equal(got.waypoints, waypoints, check_exact=False, rtol=1e-8)
