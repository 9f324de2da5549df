"""Survey processing of one walk: steps, positions, calibration, earth-frame field, headings.

Pure computation on one walk's tables (as read from the store); :mod:`survey.process_store`
runs it over a store and writes the results back. The output per walk:

- ``samples``: every magnetometer sample inside the waypoint range, positioned (x_m, y_m), with
  the calibrated device-frame field (uT), the attitude quaternion (w, x, y, z; device to map),
  the field rotated into the map frame (east, north, up, uT), its strength,
  horizontal and vertical components, azimuth and polar angle (deg), device heading and tilt
  (deg) and the attitude class of its step;
- ``steps``: every step with time, length (m), frequency (Hz), gyro and compass heading (for
  a phone carried top edge up or down, the walking axis of :mod:`survey.carried_heading`,
  turned the way the waypoints go), the walking direction from the positions, the heading
  offset (compass minus walking direction, deg; none for a carried phone) and the attitude
  class;
- ``legs``: per waypoint leg the quality flags of :mod:`survey.positions`;
- ``summary``: counts, the step-length model, the calibration decision and the walk's median
  heading offset (a constant: map rotation plus declination), reported apart from the
  spatially varying part (``heading_offset_deg - median``).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from .attitude import AttitudeParams, classify_attitude
from .carried_heading import CarriedHeadingParams, carried_heading_deg
from .errors import ProcessingError
from .field_features import circular_median_deg, field_features, unwrap_deg, wrap_deg
from .magcal import MagCalResult
from .positions import PositionParams, clean_waypoints, positions_along_walk
from .rotation import heading_deg, interpolate_rotation_vector, rotation_matrices, tilt_deg
from .sensor_units import (FIELD_MEDIAN_UT, acceleration_unit_problem, field_unit_problem,
                           gyro_turn_problem)
from .steps import detect_steps, fit_weinberg, segment_ids, weinberg_length

if TYPE_CHECKING:  # an annotation only
    import shapely

#: A gap (s) in the gyroscope's stream over which its rate is not integrated (ILC site1's
#: longest is 0.104 s; a phone's gyroscope samples at 50-500 Hz).
GYRO_GAP_S = 0.25
#: Weinberg constant used when a walk has too few legs to fit its own.
DEFAULT_WEINBERG_K = 0.4
#: A waypoint more than this (s) before a walk's first accelerometer row or after its last is
#: dropped: its leg has no steps, and the joint step-track fit bends the walk's other legs
#: towards it (a click an hour after a sample walk dropped its held-out skill from 0.45 to
#: 0.33). The ILC traces' first waypoints lie 0.19 s before the first row at most, their last
#: ones 0.33 s after the last.
MAX_WAYPOINT_OUTSIDE_SENSORS_S = 5.0


@dataclass(frozen=True)
class ProcessParams:
    """Parameters of :func:`process_walk`."""

    positions: PositionParams = field(default_factory=PositionParams)
    attitude: AttitudeParams = field(default_factory=AttitudeParams)
    #: When a step's phone counts as carried top edge up or down (its compass the walking axis).
    carried: CarriedHeadingParams = field(default_factory=CarriedHeadingParams)
    #: Plausible range of the calibrated field strength (uT); outside it a stream is not trusted.
    strength_range_ut: tuple[float, float] = FIELD_MEDIAN_UT

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)


@dataclass
class ProcessedWalk:
    trace_id: str
    samples: pd.DataFrame
    steps: pd.DataFrame
    legs: pd.DataFrame
    summary: dict
    track_t_ms: NDArray[np.float64]  # the positioned track: knot times (ms) ...
    track_xy_m: NDArray[np.float64]  # ... and positions (k, 2), map metres
    range_t_ms: tuple[float, float]  # first and last waypoint time

    def position_at(self, t_ms: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """Positions (n, 2) at times ``t_ms`` and whether each lies in the waypoint range
        (positions outside are NaN)."""
        t = np.asarray(t_ms, dtype=np.float64)
        inside = (t >= self.range_t_ms[0]) & (t <= self.range_t_ms[1])
        xy = np.full((len(t), 2), np.nan)
        xy[inside, 0] = np.interp(t[inside], self.track_t_ms, self.track_xy_m[:, 0])
        xy[inside, 1] = np.interp(t[inside], self.track_t_ms, self.track_xy_m[:, 1])
        return xy, inside


def _stream(sensors: pd.DataFrame, name: str) -> pd.DataFrame:
    rows = sensors[sensors["stream"] == name]
    return rows.sort_values("t_ms", kind="stable").reset_index(drop=True)


def accelerometer_stream(sensors: pd.DataFrame, min_rows: int = 1) -> pd.DataFrame:
    """The accelerometer rows (time-sorted): the calibrated stream when it has ``min_rows``
    rows or more, else the uncalibrated one (a phone may log only that)."""
    acc = _stream(sensors, "accelerometer")
    return acc if len(acc) >= min_rows else _stream(sensors, "accelerometer_uncalibrated")


def reported_bias(sensors: pd.DataFrame) -> NDArray[np.float64] | None:
    """The phone's own hard-iron estimate (uT): the median bias of the uncalibrated
    magnetometer stream, or None when the stream or its bias is missing (:func:`_has_bias`)."""
    unc = _stream(sensors, "magnetic_field_uncalibrated")
    if not len(unc):
        return None
    bias = unc[["bx", "by", "bz"]].to_numpy(np.float64)
    return np.median(bias, axis=0) if _has_bias(bias) else None


def _has_bias(bias: NDArray[np.float64]) -> bool:
    """Whether an uncalibrated stream's bias columns (n, 3) (uT) are an estimate: finite,
    and not 0 on every axis of every row, which a phone that estimates no hard iron (or a
    log converted from raw values) reports. Taken for the estimate, such a walk's raw field
    was "calibrated" and its sessions merged into one, leaving the map 20-45 uT off."""
    return bool(np.isfinite(bias).all() and np.any(bias != 0))


def calibration_sessions(models: list[str], biases: list[NDArray[np.float64] | None],
                         tolerance_ut: float = 2.0) -> list[str]:
    """Calibration session of each walk.

    The phone's reported bias is constant within a session and jumps by tens of uT between
    sessions, with small wobbles: walks of one device model whose biases are within
    ``tolerance_ut`` of each other (single linkage) form one session, named by the model and
    the session's median bias rounded to 1 uT. Walks without a bias get ``model|no-bias``.
    """
    keys = [""] * len(models)
    for model in sorted(set(models)):
        idx = [i for i, m in enumerate(models) if m == model and biases[i] is not None]
        for i, m in enumerate(models):
            if m == model and biases[i] is None:
                keys[i] = f"{model or 'unknown'}|no-bias"
        if not idx:
            continue
        b = np.array([biases[i] for i in idx])
        label = np.arange(len(idx))
        close = np.linalg.norm(b[:, None, :] - b[None, :, :], axis=2) <= tolerance_ut
        changed = True
        while changed:  # single linkage: propagate the smallest label through neighbours
            new = np.array([label[close[k]].min() for k in range(len(idx))])
            changed = bool((new != label).any())
            label = new
        for lab in np.unique(label):
            members = np.flatnonzero(label == lab)
            med = np.median(b[members], axis=0)
            name = f"{model or 'unknown'}|" + ",".join(f"{v:.0f}" for v in med)
            for k in members:
                keys[idx[k]] = name
    return keys


def session_device(session: str) -> str:
    """The device model of a calibration session key made by :func:`calibration_sessions`."""
    return str(session).rsplit("|", 1)[0]


#: The streams :func:`calibrated_field` takes the field from (a walk without either has none).
MAGNETOMETER_STREAMS = ("magnetic_field", "magnetic_field_uncalibrated")


def calibrated_field(sensors: pd.DataFrame, session_fit: MagCalResult | None = None,
                     strength_range_ut: tuple[float, float] = FIELD_MEDIAN_UT
                     ) -> tuple[NDArray, NDArray, str, str]:
    """Choose the magnetometer calibration of a walk.

    Order of preference: the phone's calibrated stream (if its strength is plausible); the
    uncalibrated stream minus the phone's bias; our pooled session fit (if it is well
    conditioned). Otherwise the raw stream is returned with decision ``"not-calibrated"``.

    Returns
    -------
    (t_ms (n,), field_ut (n, 3) device frame, decision, detail)
    """
    lo, hi = strength_range_ut
    cal, unc = (_stream(sensors, name) for name in MAGNETOMETER_STREAMS)

    def plausible(m: NDArray[np.float64]) -> tuple[np.bool_, np.float64]:
        s = np.median(np.linalg.norm(m, axis=1))
        return lo <= s <= hi, s

    if len(cal):
        m = cal[["x", "y", "z"]].to_numpy(np.float64)
        ok, s = plausible(m)
        if ok:
            return cal["t_ms"].to_numpy(), m, "device-calibrated", f"median strength {s:.1f} uT"
    if len(unc):
        raw = unc[["x", "y", "z"]].to_numpy(np.float64)
        bias = unc[["bx", "by", "bz"]].to_numpy(np.float64)
        if _has_bias(bias):
            m = raw - bias
            ok, s = plausible(m)
            if ok:
                return (unc["t_ms"].to_numpy(), m, "uncalibrated-minus-device-bias",
                        f"median strength {s:.1f} uT")
        if session_fit is not None and session_fit.ok:
            return (unc["t_ms"].to_numpy(), session_fit.apply(raw), "own-session-fit",
                    f"hard iron {np.round(session_fit.hard_iron_ut, 1).tolist()} uT")
        reason = session_fit.reason if session_fit is not None else "no session fit"
        return (unc["t_ms"].to_numpy(), raw, "not-calibrated",
                f"own fit ill-conditioned, not applied ({reason})")
    if len(cal):
        m = cal[["x", "y", "z"]].to_numpy(np.float64)
        return cal["t_ms"].to_numpy(), m, "not-calibrated", "calibrated stream implausible"
    raise ProcessingError("no magnetometer stream")


def field_strengths_ut(sensors: pd.DataFrame) -> dict[str, float]:
    """Median strength (uT, as logged) of each field a walk's magnetometer gives: the
    calibrated stream and the uncalibrated one minus the phone's bias (or as it is, without
    a bias); empty without a magnetometer."""
    cal, unc = (_stream(sensors, name) for name in MAGNETOMETER_STREAMS)
    out = {}
    if len(cal):
        out["calibrated"] = float(np.median(np.linalg.norm(
            cal[["x", "y", "z"]].to_numpy(np.float64), axis=1)))
    if len(unc):
        raw = unc[["x", "y", "z"]].to_numpy(np.float64)
        bias = unc[["bx", "by", "bz"]].to_numpy(np.float64)
        if _has_bias(bias):
            out["uncalibrated minus bias"] = float(np.median(np.linalg.norm(raw - bias, axis=1)))
        else:
            out["uncalibrated"] = float(np.median(np.linalg.norm(raw, axis=1)))
    return out


def unit_checked_headings(trace_id: str, sensors: pd.DataFrame, acc_xyz: NDArray[np.float64],
                          rot_t: NDArray, rot: NDArray
                          ) -> tuple[tuple[NDArray, NDArray], tuple[NDArray, NDArray] | None]:
    """The walk's compass and gyroscope heading tracks (:func:`compass_track_deg`,
    :func:`gyro_heading_deg`), once its sensors are known to be in the units indoormap
    reads: else a :class:`ProcessingError` naming the walk (:mod:`survey.sensor_units`:
    accelerometer ``acc_xyz`` (n, 3) not in m/s^2, magnetometer not in uT, gyroscope not in
    rad/s by its turns against the rotation vector's). Before step detection, which finds no
    step in an accelerometer in g."""
    compass = compass_track_deg(trace_id, rot_t, rot)
    turn = rotation_vector_turn_deg(rot_t, rot) if len(rot_t) > 1 else None
    gyro = gyro_heading_deg(sensors, rot_t, rot, turn)
    problem = (acceleration_unit_problem(acc_xyz)
               or field_unit_problem(field_strengths_ut(sensors))
               or (gyro_turn_problem(turn, gyro)
                   if gyro is not None and turn is not None else None))
    if problem:
        raise ProcessingError(f"{trace_id}: {problem}")
    return compass, gyro


def rotation_vector_turn_deg(rot_t: NDArray, rot: NDArray
                             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """How far the rotation vector turns the phone about the vertical, as a heading track
    (deg clockwise, unwrapped, arbitrary origin; ``(t_ms, heading_deg)``): the up component
    of each rotation from one sample to the next, summed. It is what
    :func:`gyro_heading_deg` integrates from the gyroscope, whatever way the phone is held:
    the compass heading (the y axis's azimuth) of a phone swinging in the hand spins by
    hundreds of degrees as its y axis passes the vertical, where the phone hardly turns."""
    r = rotation_matrices(rot)
    step = np.einsum("nij,nkj->nik", r[1:], r[:-1])  # earth-frame rotation R[k+1] R[k]^T
    turn = np.arctan2(step[:, 1, 0] - step[:, 0, 1], step[:, 0, 0] + step[:, 1, 1])
    return (np.asarray(rot_t, dtype=np.float64),
            -np.degrees(np.concatenate([[0.0], np.cumsum(turn)])))


def compass_track_deg(trace_id: str, rot_t: NDArray, rot: NDArray
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The phone's compass heading from its rotation vector, unwrapped (deg), at the samples
    where it is defined: ``(t_ms, heading_deg)`` for :func:`numpy.interp`.

    Raises
    ------
    ProcessingError
        No sample gives a heading (a phone held upright all along).
    """
    unwrapped = unwrap_deg(heading_deg(rot))
    good = np.isfinite(unwrapped)
    if not good.any():
        raise ProcessingError(f"{trace_id}: the rotation vector gives no heading (phone "
                              "upright?)")
    return np.asarray(rot_t, dtype=np.float64)[good], unwrapped[good]


def gyro_heading_deg(sensors: pd.DataFrame, rot_t: NDArray, rot: NDArray,
                     rv_turn: tuple[NDArray, NDArray] | None = None
                     ) -> tuple[NDArray, NDArray] | None:
    """Heading (deg clockwise from north, unwrapped, arbitrary origin) integrated from the
    gyroscope's rate about the vertical axis; None without a gyroscope stream.

    Over a gap in the stream longer than :data:`GYRO_GAP_S` (or five times its usual
    interval) the heading turns as the rotation vector does about the vertical
    (:func:`rotation_vector_turn_deg` between the gap's two ends; 0 for a clock step, whose
    two ends are one instant; ``rv_turn``: that track, when already made): a logging pause
    or a clock step of 30 s, integrated as one trapezoid, turned the heading by up to 1,270
    deg."""
    gyro = _stream(sensors, "gyroscope")
    if len(gyro) < 2:
        return None
    t = gyro["t_ms"].to_numpy(np.float64)
    q = interpolate_rotation_vector(rot_t, rot, t)
    r = rotation_matrices(q, quaternion=True)
    omega_up = np.einsum("nij,nj->ni", r, gyro[["x", "y", "z"]].to_numpy(np.float64))[:, 2]
    rate = -np.degrees(omega_up)  # counter-clockwise about up is a decreasing heading
    dt = np.diff(t) / 1000.0
    turn = 0.5 * (rate[1:] + rate[:-1]) * dt
    gap = dt > max(GYRO_GAP_S, 5 * float(np.median(dt)))
    if gap.any():
        if rv_turn is None and len(rot_t) > 1:
            rv_turn = rotation_vector_turn_deg(rot_t, rot)
        rt, rh = rv_turn if rv_turn is not None else (t[:1], [0.0])
        turn[gap] = np.interp(t[1:][gap], rt, rh) - np.interp(t[:-1][gap], rt, rh)
    return t, np.concatenate([[0.0], np.cumsum(turn)])


#: A phone whose y axis points within this angle (deg) of the walking direction points forward.
FORWARD_TOLERANCE_DEG = 45.0


def _forward_by_heading(att, compass_minus_walk_deg: NDArray, params: AttitudeParams
                        ) -> NDArray[np.str_]:
    """Per-step attitude with the forward test done by heading where it can be.

    The paper's per-step classes (001, Algorithm 2) decide "forward" from accelerometer events
    (E2, E3), which a phone held flat with little lateral sway leaves undecided. In a survey the
    walking direction is known: an upward phone whose y axis points within
    ``FORWARD_TOLERANCE_DEG`` of it is forward (UFH or UFNH by the incline), one pointing farther
    away is not (UNF). Steps without a known walking direction keep the paper's class.
    """
    classes = np.asarray(att.attitude, dtype=object).astype(str)
    known = np.isfinite(compass_minus_walk_deg)
    upward = np.isin(classes, ["UFH", "UFNH", "UNF"])
    forward = np.abs(compass_minus_walk_deg) <= FORWARD_TOLERANCE_DEG
    horizontal = np.abs(att.theta_deg) < params.k2 * 90.0
    out = classes.copy()
    sel = known & upward
    out[sel & forward & horizontal] = "UFH"
    out[sel & forward & ~horizontal] = "UFNH"
    out[sel & ~forward] = "UNF"
    return out


def _way_along_legs(axis_deg: NDArray, step_t_ms: NDArray, wt: NDArray, wxy: NDArray
                    ) -> NDArray[np.float64]:
    """A carried phone's walking axis (:mod:`survey.carried_heading`), turned by 180 deg
    where most of the steps inside the waypoint legs point against their leg's bearing (one
    way for the whole walk: the axis keeps its way while the phone keeps its hold)."""
    leg = segment_ids(step_t_ms, wt)
    inside = leg >= 0
    if not inside.any():
        return axis_deg
    d = wxy[leg[inside] + 1] - wxy[leg[inside]]
    bearing = np.degrees(np.arctan2(d[:, 0], d[:, 1]))
    against = np.abs(wrap_deg(axis_deg[inside] - bearing)) > 90.0
    return np.mod(axis_deg + 180.0, 360.0) if against.mean() > 0.5 else axis_deg


def waypoints_off_sensors(waypoint_t_ms: ArrayLike, acc_t_ms: ArrayLike) -> NDArray[np.bool_]:
    """Which waypoints (times, ms) lie more than :data:`MAX_WAYPOINT_OUTSIDE_SENSORS_S` before
    the first or after the last accelerometer row (times ``acc_t_ms``, ms, at least one):
    clicks that processing drops and evaluation does not score."""
    t = np.asarray(waypoint_t_ms, dtype=np.float64)
    acc = np.asarray(acc_t_ms, dtype=np.float64)
    tol_ms = 1000.0 * MAX_WAYPOINT_OUTSIDE_SENSORS_S
    return (t < acc.min() - tol_ms) | (t > acc.max() + tol_ms)


def _within_sensor_span(trace_id: str, wt: NDArray, wxy: NDArray, acc_t: NDArray
                        ) -> tuple[NDArray, NDArray, list[int]]:
    """The waypoints (times ms, positions m) not :func:`waypoints_off_sensors`, and the times
    of those dropped."""
    stray = waypoints_off_sensors(wt, acc_t)
    if not stray.any():
        return wt, wxy, []
    if (~stray).sum() < 2:
        raise ProcessingError(f"{trace_id}: {int((~stray).sum())} waypoint(s) within the "
                              f"walk's sensor rows ({int(stray.sum())} lie more than "
                              f"{MAX_WAYPOINT_OUTSIDE_SENSORS_S:g} s outside them); a walk "
                              "needs two")
    return wt[~stray], wxy[~stray], [int(t) for t in wt[stray]]


def process_walk(trace_id: str, sensors: pd.DataFrame, waypoints: pd.DataFrame,
                 params: ProcessParams = ProcessParams(), *,
                 reachable: shapely.Geometry | None = None,
                 session_fit: MagCalResult | None = None) -> ProcessedWalk:
    """Process one walk. See the module docstring for the outputs.

    Raises
    ------
    ProcessingError
        Fewer than two waypoints at distinct times, no accelerometer, no rotation vector, no
        magnetometer, or no steps.
    """
    wt, wxy, n_dup_wp = clean_waypoints(waypoints["t_ms"], waypoints[["x_m", "y_m"]])
    acc = accelerometer_stream(sensors)
    if len(acc) < 10:
        raise ProcessingError(f"{trace_id}: no accelerometer stream")
    rv = _stream(sensors, "rotation_vector")
    if len(rv) < 2:
        raise ProcessingError(f"{trace_id}: no rotation vector: cannot rotate the field into the "
                              "map frame")
    acc_t = acc["t_ms"].to_numpy(np.float64)
    acc_xyz = acc[["x", "y", "z"]].to_numpy(np.float64)
    wt, wxy, stray_wp = _within_sensor_span(trace_id, wt, wxy, acc_t)
    rot_t = rv["t_ms"].to_numpy(np.float64)
    rot = rv[["x", "y", "z"]].to_numpy(np.float64)

    # Headings: gyro (relative, immune to magnetic anomalies) and compass (rotation vector).
    compass, gyro = unit_checked_headings(trace_id, sensors, acc_xyz, rot_t, rot)

    steps = detect_steps(acc_t, acc_xyz)
    st = steps.t_ms
    if len(st) == 0:
        raise ProcessingError(f"{trace_id}: no steps detected")
    step_start = np.concatenate([[st[0] - 600.0], st[:-1]])
    step_start = np.maximum(step_start, st - 1000.0)
    mid = 0.5 * (step_start + st)
    compass_step = np.mod(np.interp(mid, *compass), 360.0)
    axis = carried_heading_deg(acc_t, acc_xyz, rot_t, rot, step_start, st, params.carried)
    carried = np.isfinite(axis)
    compass_step[carried] = _way_along_legs(axis[carried], st[carried], wt, wxy)
    if gyro is not None:
        relative_heading = np.interp(mid, *gyro)
        # Anchor the gyro's arbitrary origin to the compass over the whole walk (a median, so
        # local magnetic deviations do not move it); the shape stays the gyro's.
        relative_heading = relative_heading + circular_median_deg(
            wrap_deg(compass_step - relative_heading))
        heading_source = "gyroscope"
    else:
        relative_heading = np.interp(mid, *compass)
        heading_source = "compass"

    # Step lengths: Weinberg fitted on this walk's legs, or the default constant.
    seg = segment_ids(st, wt)
    dist = np.hypot(*np.diff(wxy, axis=0).T)
    try:
        fit = fit_weinberg(steps.delta_acc_ms2, seg, dist)
        k = fit.params[0] if fit.n_segments >= 2 else DEFAULT_WEINBERG_K
        model = {"model": "weinberg", "k": k, "fitted": fit.n_segments >= 2,
                 "residual_rms_m": fit.residual_rms_m, "n_legs": fit.n_segments}
    except ProcessingError:
        k = DEFAULT_WEINBERG_K
        model = {"model": "weinberg", "k": k, "fitted": False}
    lengths = weinberg_length(steps.delta_acc_ms2, k)

    # Calibrated field at magnetometer times, rotated into the map frame.
    mag_t, mag_dev, decision, detail = calibrated_field(sensors, session_fit,
                                                        params.strength_range_ut)
    pos = positions_along_walk(wt, wxy, mag_t, step_t_ms=st, step_heading_deg=relative_heading,
                               step_weight=lengths, params=params.positions,
                               reachable=reachable)
    inside = pos.inside
    q = interpolate_rotation_vector(rot_t, rot, mag_t[inside].astype(np.float64))
    r = rotation_matrices(q, quaternion=True)
    earth = np.einsum("nij,nj->ni", r, mag_dev[inside])
    feats = field_features(earth)

    att = classify_attitude(acc_t, acc_xyz, st, params.attitude)
    step_of_sample = np.clip(np.searchsorted(st, mag_t[inside], side="left"), 0, len(st) - 1)

    # Walking direction of each step from the final track, and the heading offset.
    kt, kxy = pos.knots_t_ms, pos.knots_xy_m
    p0 = np.column_stack([np.interp(step_start, kt, kxy[:, 0]),
                          np.interp(step_start, kt, kxy[:, 1])])
    p1 = np.column_stack([np.interp(st, kt, kxy[:, 0]), np.interp(st, kt, kxy[:, 1])])
    d = p1 - p0
    moved = np.hypot(d[:, 0], d[:, 1])
    walk_dir = np.mod(np.degrees(np.arctan2(d[:, 0], d[:, 1])), 360.0)
    step_inside = (st >= wt[0]) & (st <= wt[-1]) & (moved > 0.2)
    walk_dir[~step_inside] = np.nan
    offset = wrap_deg(compass_step - walk_dir)
    # a carried phone's axis comes from its accelerations over several steps and lags its
    # hand's wobble: the compass-deviation map takes the phones held in front only (simulated
    # site, heading-offset raster against the truth: F1-F3 1.83 / 1.96 / 3.02 deg with the
    # carried steps, 1.73 / 1.98 / 2.90 without)
    offset[carried] = np.nan
    attitude = _forward_by_heading(att, offset, params.attitude)
    valid_offset = np.isfinite(offset)
    median_offset = float(wrap_deg(circular_median_deg(offset[valid_offset]))) \
        if valid_offset.any() else float("nan")

    samples = pd.DataFrame({
        "t_ms": mag_t[inside].astype(np.int64),
        "x_m": pos.xy_m[inside, 0], "y_m": pos.xy_m[inside, 1], "leg": pos.leg[inside],
        "mag_east_ut": earth[:, 0], "mag_north_ut": earth[:, 1], "mag_up_ut": earth[:, 2],
        "mag_dev_x_ut": mag_dev[inside, 0], "mag_dev_y_ut": mag_dev[inside, 1],
        "mag_dev_z_ut": mag_dev[inside, 2],
        "q_w": q[:, 0], "q_x": q[:, 1], "q_y": q[:, 2], "q_z": q[:, 3],
        "strength_ut": feats.strength_ut, "horizontal_ut": feats.horizontal_ut,
        "vertical_ut": feats.vertical_ut, "azimuth_deg": feats.azimuth_deg,
        "polar_deg": feats.polar_deg,
        "device_heading_deg": heading_deg(q, quaternion=True),
        "tilt_deg": tilt_deg(q, quaternion=True),
        "attitude": attitude[step_of_sample],
    })
    steps_table = pd.DataFrame({
        "t_ms": st.astype(np.int64), "leg": seg, "length_m": lengths,
        "frequency_hz": steps.frequency_hz, "delta_acc_ms2": steps.delta_acc_ms2,
        "x_m": p1[:, 0], "y_m": p1[:, 1], "relative_heading_deg": np.mod(relative_heading, 360),
        "compass_heading_deg": compass_step, "walk_direction_deg": walk_dir,
        "heading_offset_deg": offset,
        "heading_offset_local_deg": wrap_deg(offset - median_offset),
        "attitude": attitude,
    })
    legs = pos.legs
    summary = {
        "trace_id": trace_id, "n_steps": int(len(st)),
        "n_samples": int(inside.sum()), "n_samples_outside_waypoints": pos.n_outside,
        "n_duplicate_waypoints": n_dup_wp, "waypoints_outside_sensors_t_ms": stray_wp,
        "n_legs": int(len(legs)),
        "n_flagged_legs": int((legs["flags"] != "").sum()),
        "walk_length_m": float(legs["distance_m"].sum()), "step_model": model,
        "heading_source": heading_source, "calibration": decision,
        "calibration_detail": detail, "heading_offset_median_deg": median_offset,
        "attitude_share": {str(a): float(np.mean(attitude == a)) for a in np.unique(attitude)},
    }
    return ProcessedWalk(trace_id, samples, steps_table, legs, summary, kt, kxy,
                         (float(wt[0]), float(wt[-1])))
