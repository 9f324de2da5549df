"""Survey processing on the simulated sample site (ground truth known) and on bad input."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from survey.errors import ProcessingError
from survey.field_features import field_features, wrap_deg
from survey.magcal import fit_ellipsoid
from survey.positions import time_linear_positions
from survey.process import calibrated_field, process_walk
from survey.rotation import interpolate_rotation_vector, rotation_matrices
from survey.trace_reader import read_trace

SITE = Path(__file__).resolve().parents[1] / "data" / "sample_site"
EXPECTED_ATTITUDE = {"flat_forward": "UFH", "upward_not_flat": "UFNH", "swinging": "NU",
                     "pocket": "NU"}


def _truth_at(truth: pd.DataFrame, t_ms) -> pd.DataFrame:
    """Truth rows at the sample times nearest to ``t_ms`` (steps fall between samples)."""
    return truth.iloc[truth.index.get_indexer(np.asarray(t_ms), method="nearest")]


@pytest.fixture(scope="module")
def walks():
    truth = json.loads((SITE / "truth" / "site.json").read_text())
    out = []
    for w in truth["walks"]:
        trace = read_trace(SITE / w["trace_path"])
        out.append({"meta": w, "trace": trace,
                    "truth": pd.read_parquet(SITE / w["truth_path"]).set_index("t_ms"),
                    "steps": pd.read_parquet(str(SITE / w["truth_path"]).replace(
                        ".parquet", ".steps.parquet")),
                    "walk": process_walk(trace.trace_id, trace.sensors, trace.waypoints)})
    return truth, out


def test_step_counts_within_two_percent(walks):
    _, ws = walks
    for w in ws:
        n_true, n = len(w["steps"]), w["walk"].summary["n_steps"]
        assert abs(n - n_true) <= max(1, 0.02 * n_true), w["meta"]["trace_id"]


def test_positions_beat_time_linear(walks):
    # 12 walks; the benchmark (benchmarks/positions.py) prints the 48-walk figures
    # (median 0.25 m, 2.4x better than time-linear).
    _, ws = walks
    err, err_tl = [], []
    for w in ws:
        s, tr = w["walk"].samples, w["trace"]
        true_xy = w["truth"].reindex(s["t_ms"])[["x_m", "y_m"]].to_numpy()
        err.append(np.hypot(*(s[["x_m", "y_m"]].to_numpy() - true_xy).T))
        tl = time_linear_positions(tr.waypoints["t_ms"], tr.waypoints[["x_m", "y_m"]], s["t_ms"])
        err_tl.append(np.hypot(*(tl.xy_m - true_xy).T))
    med, med_tl = np.median(np.concatenate(err)), np.median(np.concatenate(err_tl))
    assert med <= 0.35
    assert med_tl / med >= 1.6


def test_attitude_classes(walks):
    _, ws = walks
    right = total = 0
    for w in ws:
        modes = _truth_at(w["truth"], w["walk"].steps["t_ms"])["holding_mode"].map(
            EXPECTED_ATTITUDE)
        right += int((w["walk"].steps["attitude"].to_numpy() == modes.to_numpy()).sum())
        total += len(modes)
    assert right / total >= 0.95


def test_earth_frame_features_match_truth_within_noise(walks):
    """With the device's true calibration, our rotation of the field into the map frame gives
    the true strength and inclination (phone attitude) and azimuth (true attitude) within the
    sensor noise (~0.5 uT)."""
    truth, ws = walks
    devices = {d["device_id"]: d for d in truth["devices"]}
    sessions = {s["session_id"]: s for s in truth["sessions"]}
    for w in ws[:6]:
        tr, meta = w["trace"], w["meta"]
        soft = np.array(devices[meta["device_id"]]["soft_iron"])
        hard = np.array(sessions[meta["session_id"]]["true_hard_iron_ut"])
        unc = tr.stream("magnetic_field_uncalibrated")
        dev = np.linalg.solve(soft, (unc[["x", "y", "z"]].to_numpy(float) - hard).T).T
        t = unc["t_ms"].to_numpy(float)
        rv = tr.stream("rotation_vector")
        q = interpolate_rotation_vector(rv["t_ms"].to_numpy(float),
                                        rv[["x", "y", "z"]].to_numpy(float), t)
        got = field_features(np.einsum("nij,nj->ni", rotation_matrices(q, quaternion=True), dev))
        tt = w["truth"].reindex(unc["t_ms"])
        want = field_features(tt[["field_e_ut", "field_n_ut", "field_u_ut"]].to_numpy())
        assert np.median(np.abs(got.strength_ut - want.strength_ut)) < 0.8
        assert np.median(np.abs(got.polar_deg - want.polar_deg)) < 1.2
        q_true = tt[["qw", "qx", "qy", "qz"]].to_numpy(float)
        az = field_features(np.einsum("nij,nj->ni", rotation_matrices(q_true, quaternion=True),
                                      dev)).azimuth_deg
        assert np.median(np.abs(wrap_deg(az - want.azimuth_deg))) < 1.5


def test_heading_offset_recovers_compass_deviation(walks):
    """The fused compass heading is disturbed by the local field: heading_offset (compass minus
    walking direction) is minus the simulated field deviation."""
    _, ws = walks
    errors = []
    for w in ws:
        steps = w["walk"].steps
        deviation = _truth_at(w["truth"], steps["t_ms"])["compass_deviation_deg"].to_numpy()
        errors.append(wrap_deg(steps["heading_offset_deg"].to_numpy() + deviation))
    e = np.concatenate(errors)
    assert np.nanmedian(np.abs(e)) < 3.0


def test_calibration_decisions(walks):
    _, ws = walks
    sensors = ws[0]["trace"].sensors
    assert ws[0]["walk"].summary["calibration"] == "device-calibrated"
    no_cal = sensors[sensors["stream"] != "magnetic_field"]
    t, m, decision, _ = calibrated_field(no_cal)
    assert decision == "uncalibrated-minus-device-bias"
    unc = sensors[sensors["stream"] == "magnetic_field_uncalibrated"]
    ref = sensors[sensors["stream"] == "magnetic_field"][["x", "y", "z"]].to_numpy()
    np.testing.assert_allclose(m, ref, atol=1e-3)
    no_bias = no_cal.copy()
    no_bias.loc[no_bias["stream"] == "magnetic_field_uncalibrated", ["bx", "by", "bz"]] = np.nan
    flat_fit = fit_ellipsoid(unc[["x", "y", "z"]].to_numpy(float))  # flat-held: ill-conditioned
    _, raw, decision, detail = calibrated_field(no_bias, flat_fit)
    assert decision == "not-calibrated" and "ill-conditioned, not applied" in detail
    np.testing.assert_allclose(raw, unc[["x", "y", "z"]].to_numpy(), atol=1e-6)


def test_processed_walk_tables(walks):
    _, ws = walks
    walk = ws[0]["walk"]
    assert {"x_m", "y_m", "strength_ut", "azimuth_deg", "polar_deg", "attitude"} <= set(
        walk.samples.columns)
    assert walk.summary["n_samples_outside_waypoints"] > 0  # before the first click: dropped
    assert walk.legs["flags"].eq("").all()
    xy, inside = walk.position_at(walk.samples["t_ms"])
    np.testing.assert_allclose(xy, walk.samples[["x_m", "y_m"]].to_numpy())


# ---- bad input ---------------------------------------------------------------------------


def _walk(walks):
    return walks[1][0]["trace"]


def test_single_waypoint_and_coincident_times(walks):
    tr = _walk(walks)
    with pytest.raises(ProcessingError, match="at least two waypoints"):
        process_walk("w", tr.sensors, tr.waypoints.iloc[:1])
    same_time = tr.waypoints.copy()
    same_time["t_ms"] = same_time["t_ms"].iloc[0]
    with pytest.raises(ProcessingError, match="at least two waypoints"):
        process_walk("w", tr.sensors, same_time)


def test_waypoints_out_of_order_give_the_same_result(walks):
    tr = _walk(walks)
    a = process_walk("w", tr.sensors, tr.waypoints)
    b = process_walk("w", tr.sensors, tr.waypoints.iloc[::-1])
    pd.testing.assert_frame_equal(a.samples, b.samples)


def test_a_waypoint_outside_the_sensor_rows_is_dropped_and_said(walks):
    """A click an hour after the walk (or before it) has no steps on its leg; kept, the joint
    step-track fit bent the other legs towards it. Dropped, the samples are those of the
    clean walk; one within 5 s of the rows stays (real first clicks precede the rows)."""
    tr = _walk(walks)
    clean = process_walk("w", tr.sensors, tr.waypoints)
    t0, t1 = tr.sensors["t_ms"].min(), tr.sensors["t_ms"].max()
    for t_stray in (t1 + 3_600_000, t0 - 60_000):
        wp = pd.concat([tr.waypoints, pd.DataFrame({"t_ms": [t_stray], "x_m": [0.0],
                                                    "y_m": [0.0]})], ignore_index=True)
        walk = process_walk("w", tr.sensors, wp)
        assert walk.summary["waypoints_outside_sensors_t_ms"] == [t_stray]
        pd.testing.assert_frame_equal(walk.samples, clean.samples)
    assert clean.summary["waypoints_outside_sensors_t_ms"] == []
    near = pd.concat([tr.waypoints, pd.DataFrame({"t_ms": [t1 + 4_000], "x_m": [0.0],
                                                  "y_m": [0.0]})], ignore_index=True)
    assert process_walk("w", tr.sensors, near).summary["waypoints_outside_sensors_t_ms"] == []
    # evaluation does not score the track there either (the track stays at its last step)
    from survey.step_summaries import waypoints_of

    stray = pd.concat([tr.waypoints, pd.DataFrame({"t_ms": [t1 + 3_600_000], "x_m": [0.0],
                                                   "y_m": [0.0]})], ignore_index=True)
    t_wp, xy_wp = waypoints_of(dataclasses.replace(tr, waypoints=stray))
    np.testing.assert_array_equal(t_wp, np.sort(tr.waypoints["t_ms"].to_numpy(np.float64)))
    assert len(xy_wp) == len(tr.waypoints)
    far = tr.waypoints.copy()
    far.loc[1:, "t_ms"] += 10 * 3_600_000  # all but the first a day off
    with pytest.raises(ProcessingError, match="1 waypoint\\(s\\) within the walk's sensor rows"):
        process_walk("w", tr.sensors, far)


def test_process_store_warns_of_a_dropped_waypoint(tmp_path, monkeypatch):
    """Said by `process`; and a store processed by the version before the rule (whose walk
    kept the stray click) is processed again, not left as it was."""
    import gzip

    import survey.process_store as ps
    from survey.ingest import ingest
    from survey.process_store import process_store

    src = min((SITE / "F1" / "path_data_files").glob("*.txt.gz"))
    lines = gzip.decompress(src.read_bytes()).decode().split("\n")
    end = next(i for i, ln in enumerate(lines) if ln.startswith("#\tendTime"))
    t_end = int(lines[end - 1].split("\t")[0])
    lines.insert(end, f"{t_end + 3_600_000}\tTYPE_WAYPOINT\t5.0\t20.0")
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / src.name).write_bytes(gzip.compress("\n".join(lines).encode()))
    ingest([tmp_path / "in"], tmp_path / "store")
    with monkeypatch.context() as m:
        m.setattr(ps, "PROCESS_VERSION", ps.PROCESS_VERSION - 1)
        assert process_store(tmp_path / "store").processed
        assert not process_store(tmp_path / "store").processed  # unchanged
    report = process_store(tmp_path / "store")
    assert report.processed and [w for w in report.warnings if
                                 f"1 waypoint(s) more than 5 s outside the walk's sensor rows "
                                 f"dropped (t_ms {t_end + 3_600_000})" in w]


def test_process_store_warns_of_a_misclicked_waypoint(tmp_path):
    """One waypoint clicked 17 m from where the walker was: the map lost a third of its
    held-out skill and nothing said so but survey-report."""
    import gzip

    from survey.ingest import ingest
    from survey.process_store import process_store

    src = min((SITE / "F1" / "path_data_files").glob("*.txt.gz"))
    lines = gzip.decompress(src.read_bytes()).decode().split("\n")
    i = [k for k, ln in enumerate(lines) if "\tTYPE_WAYPOINT\t" in ln][1]
    t, kind, x, y = lines[i].split("\t")
    lines[i] = "\t".join([t, kind, f"{float(x) + 12:.1f}", f"{float(y) + 12:.1f}"])
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / src.name).write_bytes(gzip.compress("\n".join(lines).encode()))
    ingest([src], tmp_path / "clean")
    clean = process_store(tmp_path / "clean")
    assert not [w for w in clean.warnings if "misses the waypoints" in w]
    ingest([tmp_path / "in"], tmp_path / "store")
    report = process_store(tmp_path / "store")
    tid = src.name.split(".")[0]
    assert [w for w in report.warnings if w.startswith(tid) and
            "the step track misses the waypoints of" in w and "survey-report --legs" in w]
    # which the warning points to: the legs into and out of the moved waypoint (1), a row each
    from click.testing import CliRunner

    from survey.cli import main

    res = CliRunner().invoke(main, ["survey-report", "--store", str(tmp_path / "store"),
                                    "--legs", "--csv", str(tmp_path / "legs.csv")])
    assert res.exit_code == 0, res.output
    legs = pd.read_csv(tmp_path / "legs.csv")
    bent = legs[legs["flags"].str.contains("waypoint")]
    assert set(bent["trace_id"]) == {tid} and {0, 1} <= set(bent["leg"]), legs
    assert (bent["waypoint_residual_m"] > 2.0).any()  # max_waypoint_residual_m
    assert "flagged leg(s) of 1 walk(s)" in res.output and tid in res.output
    clean_legs = CliRunner().invoke(main, ["survey-report", "--store", str(tmp_path / "clean"),
                                           "--legs", "--csv", str(tmp_path / "clean.csv")])
    assert clean_legs.exit_code == 0, clean_legs.output
    assert not pd.read_csv(tmp_path / "clean.csv")["flags"].str.contains("waypoint").any()


def test_coincident_waypoints_are_flagged(walks):
    tr = _walk(walks)
    wp = tr.waypoints.copy()
    wp.loc[2, ["x_m", "y_m"]] = wp.loc[1, ["x_m", "y_m"]].to_numpy()
    walk = process_walk("w", tr.sensors, wp)
    assert "coincident" in walk.legs.loc[1, "flags"]


def test_no_steps_no_rotation_vector_no_magnetometer(walks):
    tr = _walk(walks)
    still = tr.sensors.copy()
    acc = still["stream"] == "accelerometer"
    still.loc[acc, ["x", "y", "z"]] = np.array([0.0, 0.0, 9.81], dtype=np.float32)
    with pytest.raises(ProcessingError, match="no steps"):
        process_walk("w", still, tr.waypoints)
    with pytest.raises(ProcessingError, match="no rotation vector"):
        process_walk("w", tr.sensors[tr.sensors["stream"] != "rotation_vector"], tr.waypoints)
    no_mag = tr.sensors[~tr.sensors["stream"].astype(str).str.startswith("magnetic")]
    with pytest.raises(ProcessingError, match="no magnetometer"):
        process_walk("w", no_mag, tr.waypoints)


def test_gap_in_streams_is_bridged(walks):
    tr = _walk(walks)
    t = tr.sensors["t_ms"]
    t0 = t.min() + 15_000
    gap = tr.sensors[(t < t0) | (t > t0 + 3000)]  # 3 s of every stream missing
    walk = process_walk("w", gap, tr.waypoints)
    assert walk.summary["n_steps"] > 0
    assert np.isfinite(walk.samples[["x_m", "y_m", "strength_ut"]].to_numpy()).all()


def _scaled(sensors: pd.DataFrame, prefix: str, factor: float) -> pd.DataFrame:
    """``sensors`` with every stream named ``prefix...`` (values and bias) times ``factor``."""
    out = sensors.copy()
    rows = out["stream"].astype(str).str.startswith(prefix)
    for col in ("x", "y", "z", "bx", "by", "bz"):
        out.loc[rows, col] = out.loc[rows, col] * factor
    return out


@pytest.mark.parametrize("prefix, factor, message", [
    ("accelerometer", 1 / 9.80665, r"median magnitude is 0\.99\d, where a phone reads gravity, "
                                   r"about 9\.8 m/s\^2: in g \(1 g = 9\.81 m/s\^2\), or linear "
                                   r"acceleration \(without gravity\)\?"),
    ("accelerometer", 100.0, r"median magnitude is 9\d\d, .*: in mg or cm/s\^2\?"),
    ("magnetic", 0.01, r"median strength is calibrated 0\.\d+, uncalibrated minus bias "
                       r"0\.\d+, where the Earth's field is 25-65 uT: in gauss"),
    ("magnetic", 1000.0, r"in nanotesla \(1 nT = 0\.001 uT\)\? indoormap reads uT"),
    ("gyroscope", 180 / np.pi, r"the gyroscope turns 5\d\.\d times as far as the rotation "
                               r"vector .*: in deg/s\? indoormap reads rad/s"),
    ("gyroscope", 0.01, r"turns 0\.0\d+ times as far .*: in another unit, or broken\?"),
])
def test_sensors_in_another_unit_are_named(walks, prefix, factor, message):
    """A converted log in g, gauss, nT or deg/s: the walk was processed into a wrong map
    (field layers of 0.4 "uT"; every leg missing its waypoints, blamed on the waypoints) or
    failed with "no steps detected". Processing for a map and step summaries for the
    localizer both refuse it, naming the unit the values look like."""
    from survey.step_summaries import step_summaries

    tr = _walk(walks)
    wrong = _scaled(tr.sensors, prefix, factor)
    with pytest.raises(ProcessingError, match=message):
        process_walk("w", wrong, tr.waypoints)
    with pytest.raises(ProcessingError, match=message):
        step_summaries(dataclasses.replace(tr, sensors=wrong))


def test_a_phone_swinging_in_the_hand_passes_the_gyroscope_check(tmp_path):
    """The gyroscope's turns are compared with the rotation vector's about the vertical, not
    with its compass heading: a phone swinging in the hand spins its y axis's azimuth by
    hundreds of degrees as the axis passes the vertical, and a simulated swinging walk was
    refused as "gyroscope in another unit" (seed 4's second walk: 0.098 times as far). A
    swinging walk's gyroscope in deg/s is still refused."""
    from survey.sim.site import SiteParams, simulate_site
    from survey.step_summaries import step_summaries

    params = SiteParams(seed=4, n_floors=1, walks_per_floor=2, walks_without_wifi=0,
                        holding_modes=(("swinging", 1.0),))
    simulate_site(params, tmp_path / "site")
    for trace in map(read_trace, sorted((tmp_path / "site").rglob("*.txt.gz"))):
        assert process_walk(trace.trace_id, trace.sensors, trace.waypoints).summary["n_steps"]
        assert len(step_summaries(trace).t_ms)
        wrong = _scaled(trace.sensors, "gyroscope", 180 / np.pi)
        with pytest.raises(ProcessingError, match=r"turns 5\d\.\d times as far .*in deg/s\?"):
            process_walk(trace.trace_id, wrong, trace.waypoints)


def test_a_clock_step_in_the_log_adds_no_gyroscope_turn(walks):
    """Every record from mid-walk on stamped 30 s later (an NTP step, a logging pause): the
    gyroscope's rate was integrated over the 30 s as one trapezoid, turning the heading by
    tens to hundreds of degrees, every later leg off its waypoints (blamed on the clicks)."""
    from survey.process import _stream, gyro_heading_deg

    tr = _walk(walks)
    mid = float(tr.sensors["t_ms"].median())
    stepped = tr.sensors.copy()
    stepped.loc[stepped["t_ms"] > mid, "t_ms"] += 30_000
    waypoints = tr.waypoints.copy()
    waypoints.loc[waypoints["t_ms"] > mid, "t_ms"] += 30_000

    def heading(sensors):
        rv = _stream(sensors, "rotation_vector")
        return gyro_heading_deg(sensors, rv["t_ms"].to_numpy(float),
                                rv[["x", "y", "z"]].to_numpy(float))

    (t0, h0), (t1, h1) = heading(tr.sensors), heading(stepped)
    assert np.allclose(h1[t1 <= mid], h0[t0 <= mid])
    # after the step the heading goes on as it would have, less the one usual interval lost
    assert np.abs((h1 - h0)[t1 > mid]).max() < 3.0
    plain = process_walk("w", tr.sensors, tr.waypoints).legs
    jumped = process_walk("w", stepped, waypoints).legs
    assert (jumped["flags"].str.contains("heading|waypoint")).sum() <= \
        (plain["flags"].str.contains("heading|waypoint")).sum()


def test_a_walk_without_steps_points_to_wifi_locate(walks):
    """A phone lying still (or the first seconds of an app) has no steps: the localizers,
    which move by steps, refuse it, and say what places it from its scans alone."""
    from survey.step_summaries import step_summaries

    tr = _walk(walks)
    still = tr.sensors.copy()
    acc = still["stream"] == "accelerometer"
    still.loc[acc, ["x", "y", "z"]] = [0.0, 0.0, 9.81]
    with pytest.raises(ProcessingError, match=r"no steps detected in its \d+ s of "
                                              r"accelerometer .*`indoormap wifi-locate` places"):
        step_summaries(dataclasses.replace(tr, sensors=still))


def test_a_walk_without_a_usable_rotation_vector_says_what_it_logged(walks):
    """A rotation vector logged with its fourth component (every line a bad line) or a game
    rotation vector alone: the walk was refused with "no rotation vector", which named
    neither."""
    from survey.step_summaries import step_summaries
    from survey.trace_reader import parse_trace_bytes
    from survey.trace_writer import render_trace

    text = render_trace(_walk(walks))
    five = "\n".join(line + "\t0.5" if "\tTYPE_ROTATION_VECTOR\t" in line else line
                     for line in text.splitlines()).encode()
    with pytest.raises(ProcessingError, match=r"no rotation vector: no compass heading \(its "
                       r"TYPE_ROTATION_VECTOR lines were refused as bad lines, e\.g\. .*:\d+: "
                       r"TYPE_ROTATION_VECTOR needs 4 values, got 5"):
        step_summaries(parse_trace_bytes(five))
    nan = "\n".join(re.sub(r"(\tTYPE_ROTATION_VECTOR\t)[^\t]+", r"\1NaN", line)
                    for line in text.splitlines()).encode()
    with pytest.raises(ProcessingError, match=r"refused as bad lines, e\.g\. .*:\d+: "
                                              r"TYPE_ROTATION_VECTOR: a value is NaN"):
        step_summaries(parse_trace_bytes(nan))
    game = text.replace("\tTYPE_ROTATION_VECTOR\t", "\tTYPE_GAME_ROTATION_VECTOR\t").encode()
    with pytest.raises(ProcessingError, match=r"it logs \d+ TYPE_GAME_ROTATION_VECTOR lines, "
                                              r"left out: a game rotation vector has no north"):
        step_summaries(parse_trace_bytes(game))


def test_a_turn_in_a_gap_of_the_gyroscope_is_the_rotation_vectors(walks):
    """The gyroscope silent for 2 s while the walker turns a corner: the turn in the gap is
    the rotation vector's about the vertical, so the heading after it stays right (left at
    0, the rest of the walk kept the corner's turn as an error)."""
    from survey.process import _stream, gyro_heading_deg

    tr = _walk(walks)
    rv = _stream(tr.sensors, "rotation_vector")
    rot_t, rot = rv["t_ms"].to_numpy(float), rv[["x", "y", "z"]].to_numpy(float)
    t0, h0 = gyro_heading_deg(tr.sensors, rot_t, rot)
    turned = np.interp(t0 + 2000, t0, h0) - h0  # each 2 s window's turn
    start = t0[int(np.argmax(np.abs(turned[t0 < t0[-1] - 2000])))]
    assert abs(np.interp(start + 2000, t0, h0) - np.interp(start, t0, h0)) > 45  # a corner
    gyro = tr.sensors["stream"] == "gyroscope"
    silent = tr.sensors[~(gyro & tr.sensors["t_ms"].between(start, start + 2000))]
    t1, h1 = gyro_heading_deg(silent, rot_t, rot)
    after = t1 > start + 2000
    assert np.abs(h1[after] - np.interp(t1[after], t0, h0)).max() < 5.0


def test_unit_checks_leave_what_a_phone_logs():
    """The checks judge units only: a phone's field out of range in no other unit (a
    magnet nearby) is left to the calibration, one plausible field of two is enough, and a
    walk without turns says nothing of its gyroscope."""
    from survey.sensor_units import (acceleration_unit_problem, field_unit_problem,
                                     gyro_turn_problem)

    assert field_unit_problem({"calibrated": 300.0}) is None
    assert field_unit_problem({"calibrated": 0.45, "uncalibrated minus bias": 45.0}) is None
    assert field_unit_problem({}) is None
    assert "in gauss" in field_unit_problem({"uncalibrated": 0.5})
    g = np.array([[0.0, 0.0, 9.81]]) + np.random.default_rng(0).normal(0, 2, (500, 3))
    assert acceleration_unit_problem(g) is None
    assert "linear acceleration" in acceleration_unit_problem(g - [0, 0, 9.81])
    t = np.arange(0, 60_000, 20.0)
    straight = (t, 0.5 * np.sin(t / 1000))  # a wobble of +-0.5 deg
    assert gyro_turn_problem(straight, (t, 57.3 * straight[1])) is None
