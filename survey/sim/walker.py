"""One survey walk's kinematics: the true path, the timeline, steps and waypoint clicks.

The surveyor follows a planned route (the click points, see :mod:`~survey.sim.routes`). His TRUE
path strays from the straight lines between the click points by a smooth lateral deviation
(about 1-2 m at most per leg, limited by the corridor walls), passes each click point within the
click position error (~0.3 m), and cuts corners. Along the path he walks at ~1 m/s with a step
frequency of 1.6-2.0 Hz that drifts (pace changes), stands still at the start, the end and during
a few pauses of 2-5 s, and clicks each waypoint with a timing error of ~0.3 s. The recorded
waypoint is the planned click point itself (real walks reuse a limited set of map points); the
truth keeps where he really was when he clicked.

Conventions: metres, x east, y north; ``heading_deg`` is the walking direction as an azimuth,
degrees clockwise from map north, in [0, 360).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d, maximum_filter1d

from ..errors import SimulationError
from .floorplan import Floorplan
from .signals import raised_cosine_ramp, smooth_noise

#: Arc-length resolution of the dense true path (m).
PATH_STEP_M = 0.05


@dataclass(frozen=True)
class WalkerParams:
    """How the surveyor walks and clicks.

    Attributes
    ----------
    sample_rate_hz : float
        Sensor rate (all seven sensor streams share the timestamps).
    clock_jitter_ms : float
        SD of the sample interval (ms); timestamps are integer ms, strictly increasing.
    step_freq_hz : (float, float)
        Range of a walk's mean step frequency.
    step_length_coef : (float, float)
        ``(alpha, beta)`` of the step length model ``L = alpha * f + beta`` (m/Hz, m).
    pace_change : float
        Relative SD of the slow step-frequency changes within a walk.
    pace_corr_s : float
        Correlation time of pace changes (s).
    step_length_jitter_m : float
        SD of step-to-step length changes (m).
    stray_peak_m : (float, float)
        Range of the height (m) of the lateral bow of a leg (between two clicks), before the
        walls limit it; the side is random.
    stray_full_leg_m : float
        Legs shorter than this (m) bow proportionally less.
    u_turn_offset_m, u_turn_length_m : float
        At a U-turn the way back runs ``2 * u_turn_offset_m`` beside the way in, merging over
        about ``u_turn_length_m`` (m).
    turn_smoothing_s : float
        Gaussian smoothing (s) of the body heading in time.
    corner_sigma_m : float
        Gaussian smoothing of the path (m): corner cutting.
    wall_margin_m : float
        The true path keeps at least this distance from walls and shops (m).
    click_pos_sd_m : float
        RMS distance (m, 2-D) between the true position at a click and the click point.
    click_time_sd_s : float
        SD of the click time error (s).
    n_pauses : (int, int)
        Inclusive range of the number of pauses in a walk.
    pause_s : (float, float)
        Range of pause durations (s).
    start_stand_s, end_stand_s : (float, float)
        Standing time before the first and after the last step (s).
    ramp_s : float
        Duration of the speed ramps when starting and stopping (s).
    header_lead_ms : (int, int)
        The trace's start time precedes the first sensor sample by this many ms.
    """

    sample_rate_hz: float = 50.0
    clock_jitter_ms: float = 0.4
    step_freq_hz: tuple[float, float] = (1.6, 2.0)
    step_length_coef: tuple[float, float] = (0.25, 0.13)
    pace_change: float = 0.05
    pace_corr_s: float = 5.0
    step_length_jitter_m: float = 0.02
    stray_peak_m: tuple[float, float] = (0.6, 1.8)
    stray_full_leg_m: float = 5.0
    u_turn_offset_m: float = 0.35
    u_turn_length_m: float = 1.2
    turn_smoothing_s: float = 0.25
    corner_sigma_m: float = 0.5
    wall_margin_m: float = 0.25
    click_pos_sd_m: float = 0.3
    click_time_sd_s: float = 0.3
    n_pauses: tuple[int, int] = (0, 2)
    pause_s: tuple[float, float] = (2.0, 5.0)
    start_stand_s: tuple[float, float] = (1.0, 2.5)
    end_stand_s: tuple[float, float] = (0.8, 1.5)
    ramp_s: float = 0.6
    header_lead_ms: tuple[int, int] = (100, 200)


@dataclass(frozen=True)
class TruePath:
    """Dense true path of a walk.

    Attributes
    ----------
    planned_m : numpy.ndarray, shape (m, 2)
        Points of the planned polyline (straight lines between clicks), every ``PATH_STEP_M``.
    xy_m : numpy.ndarray, shape (m, 2)
        True path at the same parameter values.
    arc_m : numpy.ndarray, shape (m,)
        Arc length along the true path (m), starting at 0.
    heading_deg : numpy.ndarray, shape (m,)
        Unwrapped walking direction (azimuth, degrees) along the true path.
    click_index : numpy.ndarray, shape (k,)
        Index into the dense arrays of each click point.
    """

    planned_m: np.ndarray
    xy_m: np.ndarray
    arc_m: np.ndarray
    heading_deg: np.ndarray
    click_index: np.ndarray


def true_path(route_m: np.ndarray, plan: Floorplan, params: WalkerParams,
              rng: np.random.Generator) -> TruePath:
    """The smooth true path around a planned route, kept inside the walkable area.

    Parameters
    ----------
    route_m : numpy.ndarray, shape (k, 2)
        Click points (m), consecutive points distinct.
    plan : Floorplan
        Gives the walkable area (the path keeps ``params.wall_margin_m`` from its boundary).
    params : WalkerParams
    rng : numpy.random.Generator
    """
    r = np.asarray(route_m, dtype=np.float64)
    if len(r) < 2:
        raise SimulationError("a route needs at least two click points")
    seg = np.diff(r, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    if np.any(seg_len <= 1e-9):
        raise SimulationError("consecutive click points coincide")
    s_k = np.concatenate([[0.0], np.cumsum(seg_len)])
    n = int(np.ceil(s_k[-1] / PATH_STEP_M)) + 1
    s = np.linspace(0.0, s_k[-1], n)
    planned = np.column_stack([np.interp(s, s_k, r[:, 0]), np.interp(s, s_k, r[:, 1])])
    leg = np.clip(np.searchsorted(s_k, s, side="right") - 1, 0, len(r) - 2)
    tangent = seg / seg_len[:, None]
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])[leg]  # left of walking direction

    ds = s[1] - s[0]
    # per leg: a bow of random side and height plus two smaller harmonics, zero at both ends;
    # short legs (lane changes) bow proportionally less
    n_leg = len(r) - 1
    u = np.clip((s - s_k[leg]) / seg_len[leg], 0.0, 1.0)
    size = np.minimum(1.0, seg_len / params.stray_full_leg_m)
    c1 = rng.choice([-1.0, 1.0], n_leg) * rng.uniform(*params.stray_peak_m, n_leg) * size
    c2 = rng.normal(0.0, 0.25, n_leg) * size
    c3 = rng.normal(0.0, 0.12, n_leg) * size
    bow = (c1[leg] * np.sin(np.pi * u) + c2[leg] * np.sin(2 * np.pi * u)
           + c3[leg] * np.sin(3 * np.pi * u))
    click_index = np.clip(np.round(s_k / ds).astype(np.int64), 0, n - 1)
    e_lat = rng.normal(0.0, params.click_pos_sd_m / np.sqrt(2.0), len(r))
    # turning back (dead ends): come back on a track beside the way in, so that the smoothed
    # path makes a small loop instead of a cusp. The loop opens towards the roomier side and the
    # click error at the turn point is put on that side too (or it would close the loop).
    cos_turn = np.einsum("ij,ij->i", tangent[:-1], tangent[1:])
    u_turns = np.flatnonzero(cos_turn < -0.5) + 1
    sides = np.empty(len(u_turns))
    for j, k in enumerate(u_turns):
        n_in = np.array([-tangent[k - 1, 1], tangent[k - 1, 0]])
        probe = r[k] + np.outer([1.0, -1.0], n_in) * (2 * params.u_turn_offset_m + 0.3)
        room = plan.is_walkable(probe[:, 0], probe[:, 1], params.wall_margin_m)
        if room[0] != room[1]:
            sides[j] = 1.0 if room[0] else -1.0
        else:
            sides[j] = 1.0 if e_lat[k] >= 0 else -1.0
        e_lat[k] = sides[j] * abs(e_lat[k])
    deviation = bow + np.interp(s, s_k, e_lat)
    for side, k in zip(sides, u_turns):
        deviation += side * params.u_turn_offset_m * np.exp(
            -0.5 * ((s - s_k[k]) / params.u_turn_length_m) ** 2)
    cand = planned + deviation[:, None] * normal
    cand = gaussian_filter1d(cand, params.corner_sigma_m / ds, axis=0, mode="nearest")

    w = np.ones(n)
    spread_n = 2 * round(1.0 / ds) + 1
    xy = cand
    for _ in range(40):
        xy = planned + w[:, None] * (cand - planned)
        bad = ~plan.is_walkable(xy[:, 0], xy[:, 1], params.wall_margin_m)
        if not bad.any():
            break
        spread = gaussian_filter1d(maximum_filter1d(bad.astype(np.float64), spread_n),
                                   0.5 / ds)
        w = np.clip(w - 0.25 * spread / spread.max(), 0.0, 1.0)
    else:
        xy = np.where(bad[:, None], planned, xy)

    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(step)])
    d = np.gradient(xy, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 0], d[:, 1]))
    return TruePath(planned, xy, arc, np.degrees(heading), click_index)


@dataclass(frozen=True)
class WalkKinematics:
    """Ground truth of one walk at the sensor sample times, plus steps and clicks.

    Attributes
    ----------
    start_ms, end_ms : int
        The trace's header start and end times (Unix ms).
    t_ms : numpy.ndarray, shape (n,), int64
        Sensor sample times (Unix ms), strictly increasing, ~50 Hz.
    t_s : numpy.ndarray, shape (n,)
        Seconds since the first sample.
    xy_m : numpy.ndarray, shape (n, 2)
        True position (m).
    heading_deg : numpy.ndarray, shape (n,)
        True walking direction, azimuth degrees in [0, 360).
    speed_mps : numpy.ndarray, shape (n,)
    step_phase : numpy.ndarray, shape (n,)
        Gait phase in steps; a step (heel strike) happens at each integer.
    step_freq_hz : numpy.ndarray, shape (n,)
        Instantaneous step frequency while walking.
    moving : numpy.ndarray, shape (n,)
        Walking amplitude in [0, 1] (0 standing, 1 walking; ramps in between).
    step_t_ms : numpy.ndarray, shape (s,), int64
        True step (heel strike) times.
    step_length_m : numpy.ndarray, shape (s,)
        Distance walked since the previous step (the first: since the start).
    step_xy_m : numpy.ndarray, shape (s, 2)
    clicks_m : numpy.ndarray, shape (k, 2)
        Click points (the recorded waypoints).
    click_t_ms : numpy.ndarray, shape (k,), int64
        Recorded click times (with timing error), strictly increasing.
    click_true_t_ms : numpy.ndarray, shape (k,), int64
        When the surveyor really passed the click point.
    click_true_xy_m : numpy.ndarray, shape (k, 2)
        Where he really was at ``click_true_t_ms``.
    path : TruePath
    length_m : float
        Length of the true path (m).
    """

    start_ms: int
    end_ms: int
    t_ms: np.ndarray
    t_s: np.ndarray
    xy_m: np.ndarray
    heading_deg: np.ndarray
    speed_mps: np.ndarray
    step_phase: np.ndarray
    step_freq_hz: np.ndarray
    moving: np.ndarray
    step_t_ms: np.ndarray
    step_length_m: np.ndarray
    step_xy_m: np.ndarray
    clicks_m: np.ndarray
    click_t_ms: np.ndarray
    click_true_t_ms: np.ndarray
    click_true_xy_m: np.ndarray
    path: TruePath
    length_m: float

    def position_at(self, t_ms: np.ndarray) -> np.ndarray:
        """True position (m) at arbitrary times (clamped to the walk), shape (len(t_ms), 2)."""
        t = np.asarray(t_ms, dtype=np.float64)
        tt = self.t_ms.astype(np.float64)
        return np.column_stack([np.interp(t, tt, self.xy_m[:, 0]),
                                np.interp(t, tt, self.xy_m[:, 1])])


def sample_times_ms(n: int, rate_hz: float, jitter_ms: float,
                    rng: np.random.Generator) -> np.ndarray:
    """``n`` integer timestamps (ms from 0), strictly increasing, mean interval 1000/rate."""
    dt = 1000.0 / rate_hz + rng.normal(0.0, jitter_ms, n)
    t = np.round(np.cumsum(dt) - dt[0]).astype(np.int64)
    idx = np.arange(n, dtype=np.int64)
    return np.maximum.accumulate(t - idx) + idx


def _first_reach(values: np.ndarray, target: float, t: np.ndarray) -> float:
    """Time at which a non-decreasing series first reaches ``target`` (linear interpolation)."""
    i = int(np.searchsorted(values, target, side="left"))
    if i <= 0:
        return float(t[0])
    if i >= len(values):
        return float(t[-1])
    v0, v1 = values[i - 1], values[i]
    frac = 0.0 if v1 <= v0 else (target - v0) / (v1 - v0)
    return float(t[i - 1] + frac * (t[i] - t[i - 1]))


def simulate_walk(route_m: np.ndarray, plan: Floorplan, start_ms: int, params: WalkerParams,
                  rng: np.random.Generator) -> WalkKinematics:
    """Walk a planned route.

    Parameters
    ----------
    route_m : numpy.ndarray, shape (k, 2)
        Click points (m).
    plan : Floorplan
    start_ms : int
        The trace's start time (Unix ms).
    params : WalkerParams
    rng : numpy.random.Generator

    Returns
    -------
    WalkKinematics
    """
    path = true_path(route_m, plan, params, rng)
    total = float(path.arc_m[-1])
    alpha, beta = params.step_length_coef
    rate = params.sample_rate_hz
    r = params.ramp_s

    t_go = rng.uniform(*params.start_stand_s)
    f0 = rng.uniform(*params.step_freq_hz)
    v0 = (alpha * f0 + beta) * f0
    expected = total / v0
    n_pause = int(rng.integers(params.n_pauses[0], params.n_pauses[1] + 1))
    pause_dur = rng.uniform(*params.pause_s, n_pause)
    pause_at = np.sort(rng.uniform(t_go + 3.0, t_go + max(expected - 3.0, 3.5), n_pause))
    keep = np.concatenate([[True], np.diff(pause_at) > pause_dur[:-1] + 4.0]) if n_pause else []
    pause_at, pause_dur = pause_at[keep], pause_dur[keep]

    duration_max = t_go + 1.6 * expected + pause_dur.sum() + params.end_stand_s[1] + 10.0
    n_max = int(np.ceil(duration_max * rate)) + 10
    lead_ms = int(rng.integers(params.header_lead_ms[0], params.header_lead_ms[1] + 1))
    t_rel_ms = sample_times_ms(n_max, rate, params.clock_jitter_ms, rng)
    t_s = t_rel_ms / 1000.0
    dt = np.diff(t_s, prepend=t_s[0])

    moving = raised_cosine_ramp(t_s - t_go, r)
    for p, dur in zip(pause_at, pause_dur):
        moving *= 1.0 - raised_cosine_ramp(t_s - (p - r), r) * (
            1.0 - raised_cosine_ramp(t_s - (p + dur), r))
    f = f0 * (1.0 + params.pace_change * smooth_noise(n_max, params.pace_corr_s * rate, rng))
    f = np.clip(f, 1.2, 2.6)
    length = alpha * f + beta + params.step_length_jitter_m * smooth_noise(n_max, 0.3 * rate, rng)
    v_free = length * f
    sigma_free = np.cumsum(v_free * moving * dt)
    stop_dist = total - 0.5 * v0 * r
    i_e = int(np.searchsorted(sigma_free, stop_dist))
    if i_e >= n_max:
        raise SimulationError("walk timeline too short; increase duration_max")
    t_e = t_s[i_e]
    moving *= 1.0 - raised_cosine_ramp(t_s - t_e, r)
    t_end = t_e + r + rng.uniform(*params.end_stand_s)
    n = int(np.searchsorted(t_s, t_end, side="right"))
    t_s, dt, moving, f, v_free = t_s[:n], dt[:n], moving[:n], f[:n], v_free[:n]
    t_rel_ms = t_rel_ms[:n]
    speed = v_free * moving
    sigma = np.minimum(np.cumsum(speed * dt), total)
    phase = rng.uniform(0.0, 0.3) + np.cumsum(f * moving * dt)

    xy = np.column_stack([np.interp(sigma, path.arc_m, path.xy_m[:, 0]),
                          np.interp(sigma, path.arc_m, path.xy_m[:, 1])])
    # body heading: the path direction, smoothed in time so that turning back on the spot (a
    # cusp of the path in a narrow corridor) takes a moment instead of an instant
    heading = gaussian_filter1d(np.interp(sigma, path.arc_m, path.heading_deg),
                                params.turn_smoothing_s * rate, mode="nearest") % 360.0

    # steps: integer crossings of the gait phase
    ks = np.arange(np.floor(phase[0]) + 1, np.floor(phase[-1]) + 1)
    idx = np.clip(np.searchsorted(phase, ks, side="left"), 1, n - 1)
    p0, p1 = phase[idx - 1], phase[idx]
    frac = np.where(p1 > p0, (ks - p0) / np.where(p1 > p0, p1 - p0, 1.0), 0.0)
    step_t = t_s[idx - 1] + frac * (t_s[idx] - t_s[idx - 1])
    step_sigma = np.interp(step_t, t_s, sigma)
    step_len = np.diff(np.concatenate([[0.0], step_sigma]))
    step_xy = np.column_stack([np.interp(step_sigma, path.arc_m, path.xy_m[:, 0]),
                               np.interp(step_sigma, path.arc_m, path.xy_m[:, 1])])

    # clicks
    t0_ms = int(start_ms) + lead_ms
    t_stop = t_e + r
    click_sigma = path.arc_m[path.click_index] + rng.normal(
        0.0, params.click_pos_sd_m / np.sqrt(2.0), len(path.click_index))
    true_t = np.empty(len(click_sigma))
    for i, sc in enumerate(click_sigma):
        if sc <= 1e-6:
            true_t[i] = rng.uniform(0.2, max(t_go, 0.3))
        elif sc >= sigma[-1] - 1e-6:
            true_t[i] = rng.uniform(min(t_stop, t_s[-1]), t_s[-1])
        else:
            true_t[i] = _first_reach(sigma, sc, t_s)
    true_t = np.maximum.accumulate(true_t)
    rec_t = true_t + rng.normal(0.0, params.click_time_sd_s, len(true_t))
    rec_t = np.clip(rec_t, -lead_ms / 1000.0, t_s[-1])
    rec_ms = np.round(rec_t * 1000.0).astype(np.int64)
    gap = np.arange(len(rec_ms), dtype=np.int64) * 50
    rec_ms = np.maximum.accumulate(rec_ms - gap) + gap
    true_ms = np.round(true_t * 1000.0).astype(np.int64)
    click_xy = np.column_stack([np.interp(true_t, t_s, xy[:, 0]),
                                np.interp(true_t, t_s, xy[:, 1])])

    t_ms = t0_ms + t_rel_ms
    end_ms = int(max(t_ms[-1], t0_ms + rec_ms.max())) + int(rng.integers(5, 40))
    return WalkKinematics(
        start_ms=int(start_ms), end_ms=end_ms, t_ms=t_ms, t_s=t_s, xy_m=xy,
        heading_deg=heading, speed_mps=speed, step_phase=phase, step_freq_hz=f, moving=moving,
        step_t_ms=t0_ms + np.round(step_t * 1000.0).astype(np.int64), step_length_m=step_len,
        step_xy_m=step_xy, clicks_m=np.asarray(route_m, dtype=np.float64),
        click_t_ms=t0_ms + rec_ms, click_true_t_ms=t0_ms + true_ms, click_true_xy_m=click_xy,
        path=path, length_m=total)
