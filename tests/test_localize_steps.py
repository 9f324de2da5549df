"""Step summaries: the survey-side converter and the runtime structure's validation."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
from localize_fixtures import SAMPLE, site_json

from localize.errors import LocalizationError
from localize.steps import AttitudeCode, RadioScan, StepSummaries, attitude_codes
from survey.errors import ProcessingError
from survey.step_summaries import StepSummaryParams, scans_of, step_summaries
from survey.trace_reader import read_trace


@pytest.fixture(scope="module")
def walk():
    w = site_json()["walks"][1]
    return w, read_trace(SAMPLE / w["trace_path"])


def test_summaries_follow_the_truth(walk):
    w, trace = walk
    s = step_summaries(trace)
    truth_steps = pd.read_parquet(SAMPLE / w["truth_path"].replace(".parquet", ".steps.parquet"))
    assert abs(len(s) - len(truth_steps)) <= 2
    assert s.trace_id == w["trace_id"] and s.floor_name == "F1" and s.site_id
    truth = pd.read_parquet(SAMPLE / w["truth_path"])
    t = truth["t_ms"].to_numpy(float)
    heading = np.degrees(np.unwrap(np.radians(truth["heading_deg"].to_numpy(float))))
    dev = truth["compass_deviation_deg"].to_numpy(float)
    true_compass = np.interp(s.t_ms - 250, t, heading - dev)
    d = (s.compass_deg - true_compass + 180) % 360 - 180
    assert np.median(np.abs(d)) < 10.0
    b = truth[["field_e_ut", "field_n_ut", "field_u_ut"]].to_numpy(float)
    true_strength = np.interp(s.t_ms - 250, t, np.linalg.norm(b, axis=1))
    # device-calibrated stream: a residual of a few uT, constant over the walk
    diff = s.strength_ut - true_strength
    assert np.std(diff) < 2.0 and abs(np.median(diff)) < 8.0
    assert np.isfinite(s.polar_deg).all() and np.isfinite(s.turn_deg).all()
    assert s.mag_offsets[-1] == len(s.mag_strength_ut) and len(s.mag_offsets) == len(s) + 1
    assert s[3].mag_strength_ut.size > 10
    assert any(sc is not None for sc in s.scans)
    assert set(np.unique(s.attitude)) <= {int(a) for a in AttitudeCode}


def test_scans_carry_row_ages(walk):
    """Every Wi-Fi row reaches the localizer with its age (the matcher down-weights old rows);
    beacons merged into a step's scan count as fresh; ``fresh`` drops old rows."""
    _, trace = walk
    s = step_summaries(trace, StepSummaryParams(include_ble=trace.ble is not None))
    scans = [sc for sc in s.scans if sc is not None]
    wifi = trace.wifi
    n_rows = wifi.drop_duplicates(["scan_t_ms", "bssid"]).groupby("scan_t_ms").size()
    assert sum(len(sc) for sc in scans_of(trace)) == n_rows.sum()
    ages = np.concatenate([sc.age_ms for sc in scans])
    assert np.isfinite(ages).all() and ages.max() > 3000
    for sc in scans:
        wifi_rows = np.char.find(sc.keys.astype(str), "ble:") < 0
        assert (sc.age_ms[~wifi_rows] == 0).all()
        kept = sc.fresh(3000)
        assert np.all(kept.age_ms <= 3000) and len(kept) == int((sc.age_ms <= 3000).sum())
    with pytest.raises(LocalizationError, match="row ages"):
        RadioScan(0, np.array(["a", "b"]), np.array([-50.0, -60.0]), np.array([0.0]))


def test_with_scans_attaches_ble_windows_as_step_summaries_attach_wifi(walk):
    """``StepSummaries.with_scans`` puts each scan on the first step at or after it, as the
    survey side puts Wi-Fi scans: given the walk's own Wi-Fi scans it gives the same steps."""
    from survey.step_summaries import ble_scans_of

    _, trace = walk
    s = step_summaries(trace)
    again = s.with_scans(scans_of(trace)[::-1])  # any order
    assert [sc is None for sc in again.scans] == [sc is None for sc in s.scans]
    assert all(a.t_ms == b.t_ms and list(a.keys) == list(b.keys)
               for a, b in zip(again.scans, s.scans) if a is not None)
    ble = ble_scans_of(trace)
    on_steps = [sc for sc in s.with_scans(ble).scans if sc is not None]
    slots = {int(np.searchsorted(s.t_ms, sc.t_ms)) for sc in ble if sc.t_ms <= s.t_ms[-1]}
    assert len(on_steps) == len(slots) > 5  # two windows within one step: the later one
    assert all("@" in k for sc in on_steps for k in sc.keys)  # keyed as the BLE fingerprints
    late = RadioScan(int(s.t_ms[-1]) + 1, np.array(["x"]), np.array([-60.0]))
    assert all(sc is None for sc in s.with_scans([late]).scans)  # after the last step: dropped
    assert all(sc is None for sc in s.with_scans([]).scans) and s.scans is not None


def test_trace_without_magnetometer(walk):
    _, trace = walk
    sensors = trace.sensors[~trace.sensors["stream"].astype(str).str.startswith("magnetic")]
    bare = type(trace)(trace.trace_id, trace.header, sensors, trace.wifi, trace.ble,
                       trace.waypoints)
    # the steps without their field (before session 45 refused: "no magnetometer stream"),
    # for the methods that walk without it (test_localize_cli: auto takes align)
    steps = step_summaries(bare)
    full = step_summaries(trace)
    assert not steps.has_magnetometer and full.has_magnetometer
    assert steps.extra["calibration"] == "no-magnetometer"
    for name in ("strength_ut", "azimuth_deg", "polar_deg"):
        assert np.isnan(getattr(steps, name)).all()
    assert len(steps.mag_strength_ut) == 0 and (steps.mag_offsets == 0).all()
    np.testing.assert_array_equal(steps.t_ms, full.t_ms)
    np.testing.assert_array_equal(steps.compass_deg, full.compass_deg)


def test_trace_without_steps(walk):
    _, trace = walk
    sensors = trace.sensors.copy()
    acc = sensors["stream"].astype(str).str.startswith("accelerometer")
    sensors.loc[acc, ["x", "y"]] = 0.0
    sensors.loc[acc, "z"] = 9.81
    still = type(trace)(trace.trace_id, trace.header, sensors, trace.wifi, trace.ble,
                        trace.waypoints)
    with pytest.raises(ProcessingError, match="no steps"):
        step_summaries(still)


def _cols(m, **over):
    base = {c: np.zeros(m) for c in ("frequency_hz", "delta_acc_ms2", "compass_deg",
                                     "turn_deg", "strength_ut", "azimuth_deg", "polar_deg")}
    base["t_ms"] = np.arange(m, dtype=float) * 500.0
    base["attitude"] = np.zeros(m, dtype=np.int8)
    base.update(over)
    return base


def test_step_summaries_validate():
    s = StepSummaries(**_cols(4, strength_ut=np.full(4, np.nan)))
    assert len(s) == 4 and s[-1].t_ms == 1500.0 and not s.has_magnetometer
    with pytest.raises(LocalizationError, match="strictly increasing"):
        StepSummaries(**_cols(3, t_ms=np.array([0.0, 0.0, 1.0])))
    with pytest.raises(LocalizationError, match="compass"):
        StepSummaries(**_cols(2, compass_deg=np.array([0.0, np.nan])))
    with pytest.raises(LocalizationError, match="column"):
        StepSummaries(**_cols(3, polar_deg=np.zeros(2)))
    with pytest.raises(LocalizationError, match="mag_offsets"):
        StepSummaries(**_cols(2), mag_offsets=np.array([0, 5]), mag_strength_ut=np.zeros(5))
    with pytest.raises(LocalizationError, match="scan"):
        StepSummaries(**_cols(2), scans=(None,))
    with pytest.raises(LocalizationError):
        RadioScan(0, np.array(["a"]), np.array([-50.0, -60.0]))
    with pytest.raises(IndexError):
        s[4]
    # one step by a whole number: a slice failed inside int(), and 1.7 gave step 1
    for bad in (slice(0, 3), 1.7, True):
        with pytest.raises(TypeError, match="index must be a whole number"):
            s[bad]
    assert s[np.int64(1)].t_ms == s[1].t_ms
    with pytest.raises(LocalizationError, match="keys must be a list of transmitter ids"):
        RadioScan(1, "abc", [-50.0])  # said "1 keys but 1 RSSI values"
    assert attitude_codes(["UFH", "NU", "?"]).tolist() == [1, 4, 0]


def test_step_summaries_round_trip_through_a_table(walk):
    """``summaries_table`` and ``StepSummaries.from_table`` are inverses for every column a
    localizer reads (a DataFrame, an Arrow table or a dict): the table lacked the gyroscope
    heading, and steps rebuilt from it walked on the compass alone, silently worse."""
    import pyarrow as pa

    from survey.step_summaries import summaries_table

    _, trace = walk
    s = step_summaries(trace)
    table = summaries_table(s)
    assert np.isfinite(table["relative_heading_deg"]).all()
    for form in (table, pa.Table.from_pandas(table), {k: table[k].to_numpy() for k in table}):
        back = StepSummaries.from_table(form, trace_id=s.trace_id)
        assert back.trace_id == s.trace_id and back.scans is None
        for name in ("t_ms", "frequency_hz", "delta_acc_ms2", "compass_deg", "turn_deg",
                     "relative_heading_deg", "strength_ut", "azimuth_deg", "polar_deg",
                     "attitude"):
            np.testing.assert_array_equal(getattr(back, name), getattr(s, name))
    with pytest.raises(LocalizationError, match="lacks column.s. relative_heading_deg"):
        StepSummaries.from_table(table.drop(columns=["relative_heading_deg"]))
    # shown in a notebook: what the walk is in a line, not every array (thousands of lines)
    shown = repr(s)
    assert "\n" not in shown and len(shown) < 200 and s.trace_id in shown
    assert re.search(rf"{len(s)} steps, \d+ s, \d+ scans, magnetometer=True\)$", shown), shown
