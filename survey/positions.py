"""Positions along a surveyed walk, between its ground-truth waypoints.

Two methods:

- ``"time"``: time-linear interpolation between consecutive waypoints (the usual baseline).
- ``"steps"`` (default): the walk's own steps shape each leg. Every detected step moves the walker
  by a step vector (relative length x unit vector of the heading during the step); the leg's
  step polyline is then mapped onto the two waypoints by a similarity transform (rotation and
  scale, as a complex factor), so the leg ends exactly at both waypoints while keeping the shape
  and the timing of the steps: pauses hold still, pace changes move faster or slower, and the
  path bends where the heading says so. Heading only needs to be right *relative* within a leg
  (the gyroscope's integrated turn rate is ideal: it is not disturbed by indoor magnetic
  anomalies); a constant offset is absorbed by the transform.

Each leg gets quality flags (see :data:`FLAGS`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from .errors import ProcessingError

if TYPE_CHECKING:  # an annotation: shapely is imported when a walk is checked against it
    import shapely

#: Leg quality flags.
FLAGS = {
    "speed": "implied speed outside [min_speed_mps, max_speed_mps]",
    "step_length": "leg distance / steps outside [min_step_m, max_step_m]",
    "heading": "step headings disagree with the leg bearing by more than max_heading_deg",
    "scale": "the steps' net displacement disagrees with the leg distance by more than "
             "max_scale_error (relative; meaningful when step weights are lengths in m)",
    "no_steps": "no steps in a leg longer than 1 m",
    "coincident": "waypoints less than 0.3 m apart",
    "waypoint": "the fitted track passes an end waypoint farther than max_waypoint_residual_m",
    "off_floor": "part of the positioned leg lies outside the reachable area",
}


@dataclass(frozen=True)
class PositionParams:
    """Parameters of :func:`positions_along_walk` (speeds m/s, lengths m, angles deg)."""

    method: Literal["steps", "time"] = "steps"
    min_speed_mps: float = 0.2
    max_speed_mps: float = 2.5
    min_step_m: float = 0.3
    max_step_m: float = 1.1
    max_heading_deg: float = 30.0
    max_scale_error: float = 0.4
    max_step_duration_s: float = 0.7
    #: Where in its stride a step event falls (0 = the step's motion ends at the event).
    step_phase: float = 0.0
    #: Click noise (m): about 0.3 m of position plus 0.3 s of timing at walking speed.
    waypoint_sigma_m: float = 0.5
    #: How much the per-leg rotation/scale factor may change from one leg to the next.
    leg_factor_sigma: float = 0.05
    #: Weak prior that the factor is 1 (headings absolute, step weights in metres).
    factor_prior_sigma: float = 0.5
    #: A fitted track passing a waypoint farther than this flags its legs ("waypoint").
    max_waypoint_residual_m: float = 2.0


@dataclass
class WalkPositions:
    """Result of :func:`positions_along_walk`.

    Attributes
    ----------
    xy_m : ndarray (n, 2)
        Position of every query time (NaN outside the first/last waypoint).
    inside : ndarray (n,) bool
        Query time lies within [first waypoint, last waypoint].
    leg : ndarray (n,) int
        Leg index of every query time (-1 outside).
    legs : DataFrame
        One row per leg: t_start_ms, t_end_ms, distance_m, duration_s, n_steps, speed_mps,
        step_m, heading_rotation_deg, scale, method, flags (comma-separated).
    knots_t_ms, knots_xy_m : ndarray
        The piecewise-linear track the positions were interpolated from.
    """

    xy_m: NDArray[np.float64]
    inside: NDArray[np.bool_]
    leg: NDArray[np.int64]
    legs: pd.DataFrame
    knots_t_ms: NDArray[np.float64]
    knots_xy_m: NDArray[np.float64]

    @property
    def n_outside(self) -> int:
        return int((~self.inside).sum())


def clean_waypoints(t_ms: ArrayLike, xy_m: ArrayLike) -> tuple[NDArray, NDArray, int]:
    """Waypoints sorted by time with repeated timestamps removed (first kept).

    Returns (t_ms, xy_m, number removed). Raises :class:`ProcessingError` with fewer than two
    distinct waypoint times or non-finite values.
    """
    t = np.asarray(t_ms, dtype=np.float64)
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    if len(t) != len(xy):
        raise ProcessingError(f"waypoints: {len(t)} times for {len(xy)} positions")
    if not (np.isfinite(t).all() and np.isfinite(xy).all()):
        raise ProcessingError("waypoints: non-finite time or position")
    order = np.argsort(t, kind="stable")
    t, xy = t[order], xy[order]
    keep = np.ones(len(t), dtype=bool)
    keep[1:] = np.diff(t) > 0
    if keep.sum() < 2:
        raise ProcessingError(f"a walk needs at least two waypoints at distinct times, got "
                              f"{int(keep.sum())}")
    return t[keep], xy[keep], int((~keep).sum())


def positions_along_walk(waypoint_t_ms: ArrayLike, waypoint_xy_m: ArrayLike,
                         query_t_ms: ArrayLike, *, step_t_ms: ArrayLike | None = None,
                         step_heading_deg: ArrayLike | None = None,
                         step_weight: ArrayLike | None = None,
                         params: PositionParams = PositionParams(),
                         reachable: shapely.Geometry | None = None) -> WalkPositions:
    """Positions (map metres) at ``query_t_ms`` along a walk with ground-truth waypoints.

    Parameters
    ----------
    waypoint_t_ms, waypoint_xy_m : array (m,), (m, 2)
        Ground-truth clicks; at least two distinct times.
    query_t_ms : array (n,)
        Times to position (sensor samples, scans, ...).
    step_t_ms, step_heading_deg : array (k,), optional
        Step times and walking heading during each step (deg clockwise from map north; only
        relative heading within a leg matters). Required for ``method="steps"``.
    step_weight : array (k,), optional
        Relative step lengths (e.g. from a step-length model); default all 1.
    params : PositionParams
    reachable : shapely geometry, optional
        Reachable area; legs whose track leaves it are flagged ``off_floor``.
    """
    wt, wxy, _ = clean_waypoints(waypoint_t_ms, waypoint_xy_m)
    q = np.asarray(query_t_ms, dtype=np.float64)
    n_legs = len(wt) - 1
    leg_dist = np.hypot(*np.diff(wxy, axis=0).T)
    leg_dur = np.diff(wt) / 1000.0
    n_steps = np.zeros(n_legs, dtype=np.int64)
    factors = np.full(n_legs, np.nan + 0j)
    residual = np.full(len(wt), np.nan)
    kt, kxy, method = wt, wxy, "time"
    if params.method == "steps":
        if step_t_ms is None or step_heading_deg is None:
            raise ProcessingError("method 'steps' needs step times and headings")
        st = np.asarray(step_t_ms, dtype=np.float64)
        sh = np.radians(np.asarray(step_heading_deg, dtype=np.float64))
        sw = np.ones_like(st) if step_weight is None else np.asarray(step_weight, np.float64)
        if not (len(st) == len(sh) == len(sw)):
            raise ProcessingError("step times, headings and weights differ in length")
        order = np.argsort(st, kind="stable")
        st, sh, sw = st[order], sh[order], sw[order]
        legs_of_steps = np.searchsorted(wt, st, side="left") - 1
        n_steps = np.bincount(legs_of_steps[(legs_of_steps >= 0) & (legs_of_steps < n_legs)],
                              minlength=n_legs)
        use = (st > wt[0]) & np.isfinite(sh) & np.isfinite(sw)
        if use.sum() >= 2:
            kt, kxy, factors, residual = _fit_step_track(wt, wxy, st[use], sh[use], sw[use],
                                                         params)
            method = "steps"
    rows = []
    median_rot = np.degrees(np.angle(np.nanmean(factors / np.abs(factors)))) \
        if method == "steps" else 0.0
    for i in range(n_legs):
        flags = []
        dist, dur, n = float(leg_dist[i]), float(leg_dur[i]), int(n_steps[i])
        rot = float(np.degrees(np.angle(factors[i]))) if method == "steps" else np.nan
        scale = float(np.abs(factors[i])) if method == "steps" else np.nan
        if dist < 0.3:
            flags.append("coincident")
        if method == "steps":
            if n == 0 and dist > 1.0:
                flags.append("no_steps")
            if abs(((rot - median_rot) + 180) % 360 - 180) > params.max_heading_deg:
                flags.append("heading")
            if not np.isfinite(scale) or abs(np.log(max(scale, 1e-9))) > np.log1p(
                    params.max_scale_error):
                flags.append("scale")
            if np.nanmax(residual[i:i + 2]) > params.max_waypoint_residual_m:
                flags.append("waypoint")
        if n and dist >= 1.0 and not (params.min_step_m <= dist / n <= params.max_step_m):
            flags.append("step_length")
        if dist >= 0.3 and not (params.min_speed_mps <= dist / dur <= params.max_speed_mps):
            flags.append("speed")
        if reachable is not None:
            sel = (kt >= wt[i]) & (kt <= wt[i + 1])
            if not _inside(reachable, kxy[sel]):
                flags.append("off_floor")
        rows.append({"leg": i, "t_start_ms": wt[i], "t_end_ms": wt[i + 1], "distance_m": dist,
                     "duration_s": dur, "n_steps": n, "speed_mps": dist / dur,
                     "step_m": dist / n if n else np.nan, "heading_rotation_deg": rot,
                     "scale": scale, "waypoint_residual_m": float(residual[i + 1]),
                     "method": method, "flags": ",".join(flags)})
    inside = (q >= wt[0]) & (q <= wt[-1])
    xy = np.full((len(q), 2), np.nan)
    xy[inside, 0] = np.interp(q[inside], kt, kxy[:, 0])
    xy[inside, 1] = np.interp(q[inside], kt, kxy[:, 1])
    leg = np.where(inside, np.clip(np.searchsorted(wt, q, side="right") - 1, 0, n_legs - 1), -1)
    return WalkPositions(xy, inside, leg, pd.DataFrame(rows), kt, kxy)


def _fit_step_track(wt, wxy, st, sh, sw, params: PositionParams):
    """Least-squares step track through noisy waypoints.

    The track is ``P(t) = P0 + sum_i frac_i(t) * a_leg(i) * u_i``: step ``i`` moves the walker
    by ``u_i`` (weight x unit heading vector, as a complex number x + iy) during
    ``[start_i, t_i]``, and every leg has one complex factor ``a_j`` (rotation and scale).
    ``P0`` and the factors minimise, by linear least squares,
    ``sum_w |P(t_w) - W_w|^2 / sigma_w^2 + sum_j |a_j - a_j+1|^2 / sigma_a^2
    + sum_j |a_j - 1|^2 / sigma_prior^2``: clicks are noisy observations, not hard constraints,
    and neighbouring legs share heading and scale unless the clicks say otherwise.

    Returns (knot times, knot xy (k, 2), factor per leg, residual per waypoint in m).
    """
    n_legs = len(wt) - 1
    prev = np.concatenate([[wt[0]], st[:-1]])
    dur = np.minimum(st - prev, params.max_step_duration_s * 1000.0)
    # A step event (acceleration peak) falls inside the stride: the motion of step i spans
    # [t_i - (1 - phase) * d_i, t_i + phase * d_i].
    shift = params.step_phase * dur
    st = st + shift
    start = np.maximum(np.maximum(st - dur, prev + np.concatenate([[0.0], shift[:-1]])), wt[0])
    u = sw * np.exp(1j * (np.pi / 2 - sh))  # x east + i y north; heading clockwise from north
    leg = np.clip(np.searchsorted(wt, st, side="left") - 1, 0, n_legs - 1)
    frac = np.clip((wt[:, None] - start[None, :]) / np.maximum(st - start, 1.0)[None, :], 0, 1)
    onehot = np.zeros((len(st), n_legs), dtype=complex)
    onehot[np.arange(len(st)), leg] = u
    g = frac @ onehot  # (W, L): displacement per leg reached at each waypoint time
    sw_, sa, sp = params.waypoint_sigma_m, params.leg_factor_sigma, params.factor_prior_sigma
    rows_a = [np.hstack([np.ones((len(wt), 1)), g]) / sw_]
    rows_b = [(wxy[:, 0] + 1j * wxy[:, 1]) / sw_]
    if n_legs > 1:
        diff = np.zeros((n_legs - 1, n_legs + 1), dtype=complex)
        diff[np.arange(n_legs - 1), np.arange(1, n_legs)] = 1
        diff[np.arange(n_legs - 1), np.arange(2, n_legs + 1)] = -1
        rows_a.append(diff / sa)
        rows_b.append(np.zeros(n_legs - 1, dtype=complex))
    prior = np.zeros((n_legs, n_legs + 1), dtype=complex)
    prior[np.arange(n_legs), np.arange(1, n_legs + 1)] = 1
    rows_a.append(prior / sp)
    rows_b.append(np.ones(n_legs, dtype=complex) / sp)
    a_mat, b_vec = np.vstack(rows_a), np.concatenate(rows_b)
    x = np.linalg.lstsq(a_mat, b_vec, rcond=None)[0]
    p0, factors = x[0], x[1:]
    residual = np.abs(p0 + g @ factors - (wxy[:, 0] + 1j * wxy[:, 1]))
    ends = p0 + np.cumsum(factors[leg] * u)
    begins = np.concatenate([[p0], ends[:-1]])
    times = np.concatenate([[wt[0]], np.column_stack([start, st]).ravel(), [max(wt[-1], st[-1])]])
    pts = np.concatenate([[p0], np.column_stack([begins, ends]).ravel(), [ends[-1]]])
    times = np.maximum.accumulate(times)
    return times, np.column_stack([pts.real, pts.imag]), factors, residual


def _inside(reachable, xy: NDArray, tolerance_m: float = 0.25) -> bool:
    import shapely

    pts = shapely.points(xy)
    return bool(np.all(shapely.dwithin(reachable, pts, tolerance_m)))


def time_linear_positions(waypoint_t_ms: ArrayLike, waypoint_xy_m: ArrayLike,
                          query_t_ms: ArrayLike) -> WalkPositions:
    """Time-linear interpolation between waypoints (the baseline)."""
    return positions_along_walk(waypoint_t_ms, waypoint_xy_m, query_t_ms,
                                params=PositionParams(method="time"))
