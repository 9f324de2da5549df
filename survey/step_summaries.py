"""Trace -> per-step summaries for the localizer (:class:`localize.steps.StepSummaries`).

The runtime (:mod:`localize`) reads numpy step summaries only; this module does the sensor
processing on the survey side with the same building blocks as :mod:`survey.process`:

- steps from the accelerometer (:func:`survey.steps.detect_steps`): time, frequency and the
  peak-to-valley swing;
- compass heading of the phone at the middle of each step cycle from the rotation vector
  (:func:`survey.rotation.heading_deg`); on cycles where the phone's top edge points up or
  down (a swinging hand, a pocket) the walking axis instead
  (:func:`survey.carried_heading.carried_heading_deg`), and the turn of each step from the
  gyroscope about the vertical (:func:`survey.process.gyro_heading_deg`; the compass when
  there is no gyroscope);
- the magnetometer, calibrated as :func:`survey.process.calibrated_field` decides (device-
  calibrated stream first), rotated into the earth frame with the interpolated rotation vector;
  its features (:func:`survey.field_features.field_features`) averaged over each step cycle
  (strength, polar: mean; azimuth: circular mean), and the raw strength samples per step (DTW);
- the attitude class of each step (:func:`survey.attitude.classify_attitude`, paper 001
  Algorithm 2);
- Wi-Fi scans (each row with its age; optionally only rows seen within ``max_scan_age_ms``),
  and optionally beacons, attached to the first step at or after the scan.

A step's cycle is the interval from the previous step (at most one second back) to the step.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from localize.steps import TABLE_COLUMNS, AttitudeCode, RadioScan, StepSummaries, \
    attach_scans, attitude_codes, ble_transmitter_ids
from survey.attitude import AttitudeParams, classify_attitude
from survey.carried_heading import CarriedHeadingParams, carried_heading_deg
from survey.errors import ProcessingError, require_type
from survey.field_features import field_features
from survey.process import MAGNETOMETER_STREAMS, _stream, accelerometer_stream, calibrated_field, \
    unit_checked_headings, waypoints_off_sensors
from survey.rotation import interpolate_rotation_vector, rotation_matrices
from survey.steps import detect_steps
from survey.trace_format import ParseReport, Trace

__all__ = ["StepSummaryParams", "scans_of", "step_summaries", "summaries_table", "waypoints_of"]


@dataclass(frozen=True)
class StepSummaryParams:
    """Options of :func:`step_summaries`.

    Attributes
    ----------
    max_cycle_ms : float
        Longest step cycle (ms): the first step after a pause looks back at most this far.
    max_scan_age_ms : int, optional
        Wi-Fi rows last seen longer ago than this before their scan are dropped (ms). None
        (default) keeps every row with its age and lets the matcher down-weight the old ones
        (:data:`localize.radio_match.AGE_FRESH_MS`; site1, 10-fold: 3.65 m median against
        3.84 m for a 3 s cut and 4.30 m for every row in full).
    include_ble : bool
        Add beacon sightings (key ``ble:<uuid>:<major>:<minor>``) to the scan of their step.
    attitude : AttitudeParams
    carried : CarriedHeadingParams
        When a step's top edge counts as pointing up or down (its compass is then the
        walking axis, and its attitude :attr:`localize.steps.AttitudeCode.CARRIED`).
    """

    max_cycle_ms: float = 1000.0
    max_scan_age_ms: int | None = None
    include_ble: bool = False
    attitude: AttitudeParams = field(default_factory=AttitudeParams)
    carried: CarriedHeadingParams = field(default_factory=CarriedHeadingParams)


#: How to get a :class:`Trace` (what a wrong-type error suggests).
READ_HINT = "survey.trace_reader.read_trace(path) parses a trace file"


def scans_of(trace: Trace, max_age_ms: float | None = None) -> list[RadioScan]:
    """The Wi-Fi scans of a trace, by time, each row with its age (ms; the matchers
    down-weight old rows, :data:`localize.radio_match.AGE_FRESH_MS`). ``max_age_ms`` drops
    older rows (None keeps all)."""
    require_type(trace, Trace, "scans_of", READ_HINT)
    wifi = trace.wifi
    if wifi is None or not len(wifi):
        return []
    has_age = "age_ms" in wifi
    w = wifi[wifi["age_ms"] <= max_age_ms] if has_age and max_age_ms is not None else wifi
    out = []
    for t, g in w.groupby("scan_t_ms", sort=True):
        g = g.drop_duplicates("bssid", keep="first")
        out.append(RadioScan(int(t), g["bssid"].to_numpy().astype(str),
                             g["rssi_dbm"].to_numpy(np.float64),
                             g["age_ms"].to_numpy(np.float64) if has_age else None))
    return out


def ble_scans_of(trace: Trace, window_ms: int = 2000) -> list[RadioScan]:
    """BLE sightings of a trace grouped into windows of ``window_ms`` from its first sighting
    (one "scan" per window: mean RSSI per transmitter ``uuid:major:minor@mac``, see
    :func:`localize.steps.ble_transmitter_ids`), the way
    :func:`mapping.radio_scans.ble_observations` groups survey rows. Time = the window's last
    sighting (ms)."""
    require_type(trace, Trace, "ble_scans_of", READ_HINT)
    ble = trace.ble
    if ble is None or not len(ble):
        return []
    t = ble["t_ms"].to_numpy(np.int64)
    frame = pd.DataFrame({"win": (t - t.min()) // int(window_ms), "t_ms": t,
                          "key": ble_transmitter_ids(
                              ble["key"].to_numpy(),
                              ble["mac"].fillna("").to_numpy() if "mac" in ble else None),
                          "rssi_dbm": ble["rssi_dbm"].to_numpy(np.float64)})
    out = []
    for _, g in frame.groupby("win", sort=True):
        mean = g.groupby("key", sort=True)["rssi_dbm"].mean()
        out.append(RadioScan(int(g["t_ms"].max()), mean.index.to_numpy().astype(str),
                             mean.to_numpy(np.float64)))
    return out


def _ble_scans(trace: Trace, step_t: NDArray) -> dict[int, tuple[list[str], list[float]]]:
    ble = trace.ble
    if ble is None or not len(ble):
        return {}
    idx = np.searchsorted(step_t, ble["t_ms"].to_numpy(np.float64), side="left")
    out: dict[int, tuple[list[str], list[float]]] = {}
    for i, key, rssi in zip(idx, ble["key"].astype(str), ble["rssi_dbm"].to_numpy(float)):
        if i >= len(step_t):
            continue
        keys, vals = out.setdefault(int(i), ([], []))
        k = f"ble:{key}"
        if k not in keys:
            keys.append(k)
            vals.append(rssi)
    return out


def _cycle_bounds(st: NDArray[np.float64], max_cycle_ms: float) -> NDArray[np.float64]:
    first = st[1] - st[0] if len(st) > 1 else 600.0
    start = np.concatenate([[st[0] - min(first, max_cycle_ms)], st[:-1]])
    return np.maximum(start, st - max_cycle_ms)


def _rotation_vector_lines(report: ParseReport) -> str:
    """What a trace without a usable rotation vector logged instead, for its refusal: its
    ``TYPE_ROTATION_VECTOR`` lines refused as bad (the first's reason), or a game rotation
    vector, which has no north (it was left out as an undocumented type, unsaid)."""
    said = next((m for m in report.messages if "TYPE_ROTATION_VECTOR" in m), None)
    if said is not None:
        return f" (its TYPE_ROTATION_VECTOR lines were refused as bad lines, e.g. {said})"
    game = report.skipped.get("TYPE_GAME_ROTATION_VECTOR", 0)
    if game:
        return (f" (it logs {game} TYPE_GAME_ROTATION_VECTOR lines, left out: a game rotation "
                "vector has no north; log Android's TYPE_ROTATION_VECTOR)")
    return ""


def step_summaries(trace: Trace, params: StepSummaryParams = StepSummaryParams()
                   ) -> StepSummaries:
    """Per-step summaries of a trace for the localizer.

    Parameters
    ----------
    trace : Trace
        A parsed trace (:func:`survey.trace_reader.read_trace`).
    params : StepSummaryParams

    Returns
    -------
    StepSummaries
        One record per detected step, with the walk's site and floor ids from the header.

    Raises
    ------
    ProcessingError
        No accelerometer, no rotation vector, or no steps. A walk without a magnetometer
        stream has steps whose field features are NaN (``has_magnetometer`` false).
    TypeError
        ``trace`` is not a :class:`Trace` (a path, say).
    """
    require_type(trace, Trace, "step_summaries", READ_HINT)
    tid = trace.trace_id
    acc = accelerometer_stream(trace.sensors, min_rows=10)
    if len(acc) < 10:
        raise ProcessingError(f"{tid}: no accelerometer stream: no steps can be detected")
    rv = _stream(trace.sensors, "rotation_vector")
    if len(rv) < 2:
        raise ProcessingError(f"{tid}: no rotation vector: no compass heading"
                              + _rotation_vector_lines(trace.report))
    acc_t = acc["t_ms"].to_numpy(np.float64)
    acc_xyz = acc[["x", "y", "z"]].to_numpy(np.float64)
    rot_t = rv["t_ms"].to_numpy(np.float64)
    rot = rv[["x", "y", "z"]].to_numpy(np.float64)
    if trace.sensors["stream"].isin(MAGNETOMETER_STREAMS).any():
        mag_t, mag_dev, decision, _ = calibrated_field(trace.sensors)
    else:  # the steps' field is NaN: methods without the magnetic update still localize it
        mag_t, mag_dev, decision = np.empty(0), np.empty((0, 3)), "no-magnetometer"

    compass, gyro = unit_checked_headings(tid, trace.sensors, acc_xyz, rot_t, rot)
    steps = detect_steps(acc_t, acc_xyz)
    st = steps.t_ms
    if len(st) == 0:
        span = (acc_t[-1] - acc_t[0]) / 1000 if len(acc_t) else 0.0
        raise ProcessingError(f"{tid}: no steps detected in its {span:.0f} s of accelerometer "
                              "(the phone was not carried by a walker?): the localizers move "
                              "by steps; `indoormap wifi-locate` places a walk by its radio "
                              "scans alone")
    start = _cycle_bounds(st, params.max_cycle_ms)
    mid = 0.5 * (start + st)

    compass_mid = np.mod(np.interp(mid, *compass), 360.0)
    axis = carried_heading_deg(acc_t, acc_xyz, rot_t, rot, start, st, params.carried)
    carried = np.isfinite(axis)
    compass_mid[carried] = axis[carried]
    if gyro is not None:
        rel_start = np.interp(start, *gyro)
        rel_end = np.interp(st, *gyro)
        relative = np.interp(mid, *gyro)
    else:
        rel_start = np.interp(start, *compass)
        rel_end = np.interp(st, *compass)
        relative = np.full(len(st), np.nan)
    turn = rel_end - rel_start

    mag_t = np.asarray(mag_t, dtype=np.float64)
    order = np.argsort(mag_t, kind="stable")
    mag_t, mag_dev = mag_t[order], mag_dev[order]
    q = interpolate_rotation_vector(rot_t, rot, mag_t)
    earth = np.einsum("nij,nj->ni", rotation_matrices(q, quaternion=True), mag_dev)
    feats = field_features(earth)
    lo = np.searchsorted(mag_t, start, side="right")
    hi = np.searchsorted(mag_t, st, side="right")
    cnt = hi - lo

    def cycle_mean(v: NDArray) -> NDArray:
        c = np.concatenate([[0.0], np.cumsum(v)])
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(cnt > 0, (c[hi] - c[lo]) / np.maximum(cnt, 1), np.nan)

    strength = cycle_mean(feats.strength_ut)
    polar = cycle_mean(feats.polar_deg)
    az = np.radians(feats.azimuth_deg)  # an undefined azimuth adds nothing to the mean
    azimuth = np.mod(np.degrees(np.arctan2(cycle_mean(np.nan_to_num(np.sin(az))),
                                           cycle_mean(np.nan_to_num(np.cos(az))))), 360.0)
    azimuth[~(cycle_mean(np.isfinite(az).astype(np.float64)) > 0)] = np.nan  # none defined
    raw_strength = np.linalg.norm(mag_dev, axis=1)
    offsets = np.concatenate([[0], np.cumsum(cnt)]).astype(np.int64)
    raw = np.concatenate([raw_strength[a:b] for a, b in zip(lo, hi)]) if len(st) else \
        np.empty(0)

    att = classify_attitude(acc_t, acc_xyz, st, params.attitude)
    attitude = attitude_codes(att.attitude)
    attitude[carried] = AttitudeCode.CARRIED  # their compass is an axis

    scans = attach_scans(st, scans_of(trace, params.max_scan_age_ms))
    if params.include_ble:
        for i, (keys, vals) in _ble_scans(trace, st).items():
            old = scans[i]
            k = (old.keys.tolist() if old else []) + keys
            v = (old.rssi_dbm.tolist() if old else []) + vals
            age = np.full(len(k), np.nan)  # Wi-Fi rows keep theirs; beacons seen in the step
            age[len(k) - len(keys):] = 0.0
            if old is not None and old.age_ms is not None:
                age[:len(old)] = old.age_ms
            scans[i] = RadioScan(int(st[i]) if old is None else old.t_ms, np.asarray(k),
                                 np.asarray(v, dtype=np.float64), age)

    h = trace.header
    return StepSummaries(
        t_ms=st, frequency_hz=steps.frequency_hz, delta_acc_ms2=steps.delta_acc_ms2,
        compass_deg=compass_mid, turn_deg=turn, strength_ut=strength, azimuth_deg=azimuth,
        polar_deg=polar, attitude=attitude,
        relative_heading_deg=relative, mag_offsets=offsets, mag_strength_ut=raw,
        scans=tuple(scans), trace_id=tid, site_id=h.site_id or "", floor_id=h.floor_id or "",
        floor_name=h.floor_name or "", extra={"calibration": decision})


def waypoints_of(trace: Trace) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Waypoint times (ms) and positions (k, 2) of a trace, time-sorted, without those far
    outside its accelerometer rows (:func:`survey.process.waypoints_off_sensors`: processing
    drops them, and a track cannot be scored there)."""
    require_type(trace, Trace, "waypoints_of", READ_HINT)
    wp = trace.waypoints
    if wp is None or not len(wp):
        return np.empty(0), np.empty((0, 2))
    acc = accelerometer_stream(trace.sensors, min_rows=10)  # what the steps come from
    if len(acc):  # without any, the walk has no steps and no track to score
        wp = wp[~waypoints_off_sensors(wp["t_ms"], acc["t_ms"])]
    wp = wp.sort_values("t_ms", kind="stable")
    return wp["t_ms"].to_numpy(np.float64), wp[["x_m", "y_m"]].to_numpy(np.float64)


def summaries_table(steps: StepSummaries) -> pd.DataFrame:
    """The scalar columns of step summaries as a table (inspection, CSV); every column
    :meth:`~localize.steps.StepSummaries.from_table` reads back (the scans and the raw
    magnetometer samples are not in it: ``has_scan`` says which steps had a scan)."""
    return pd.DataFrame({  # t_ms as float: fractions of a ms kept
        **{name: getattr(steps, name) for name in TABLE_COLUMNS},
        "has_scan": [s is not None for s in (steps.scans or [None] * len(steps))]})
