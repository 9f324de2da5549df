"""Step detection from the accelerometer, and step-length models with their fits.

Detection (the step detector that drives particle motion, paper 001 Algorithm 1 / ref. 44):
the norm of the device-frame acceleration (orientation free) is resampled onto a uniform grid,
low-passed with a zero-phase Butterworth filter (default 4th order, 3 Hz, applied forward and
backward) and its peaks are steps when

* they are at least ``min_interval_s`` apart (default 0.3 s, i.e. at most 3.3 steps/s);
* their prominence exceeds an absolute threshold ``max(min_prominence_ms2,
  noise_factor * sigma_filtered)``, where ``sigma_filtered`` is the sensor white noise (estimated
  robustly from second differences of the raw norm) carried through the filter -- so pauses, where
  the filtered norm is noise only, produce no steps whatever the phone's noise level;
* the moving standard deviation of the filtered norm over ``activity_window_s`` around the peak is
  at least ``activity_factor * sigma_filtered`` (walking, not a lone noise excursion);
* their prominence is at least ``relative_prominence`` times the median prominence of the
  candidate peaks within +-``relative_window_s / 2`` -- this removes the weaker secondary bumps of
  a vigorous walker without a fixed threshold that would miss a weak walker.

Step-length models:

* Weinberg (paper 002): ``L = K * (a_max - a_min)^(1/4)`` with ``a_max - a_min`` the peak-to-valley
  swing of the filtered acceleration over the step (m/s^2);
* frequency-linear (paper 001 eq. 13 without the per-particle drift, paper 003 eq. 7):
  ``L = alpha * f + beta``, with ``alpha`` in [0.1, 1] m and ``beta`` in [-0.5, 0] m (NOTES.md);
* turn correction (paper 001 eq. 14): ``L_turn = L * sin((pi - theta) / 2)``.

Both models are fitted to waypoint legs: the step lengths of the steps taken between two
waypoints must add up to the distance between the waypoints (robust least squares, bounded).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize, signal

from survey.errors import ProcessingError
from survey.trace_format import MAX_FROM_MEDIAN_TIME_MS

__all__ = [
    "STANDARD_GRAVITY",
    "StepLengthFit",
    "Steps",
    "acceleration_magnitude",
    "detect_steps",
    "fit_frequency_model",
    "fit_weinberg",
    "frequency_length",
    "segment_ids",
    "turn_corrected_length",
    "weinberg_length",
]

#: Standard gravity (m/s^2).
STANDARD_GRAVITY = 9.80665


@dataclass(frozen=True)
class Steps:
    """Detected steps; every array has shape (m,), one entry per step (time-sorted).

    Attributes
    ----------
    t_ms : ndarray of float
        Step time (ms, same clock as the input): the peak of the filtered acceleration norm,
        refined to sub-sample precision by a parabola through the three highest samples.
    peak_acc_ms2 : ndarray
        Filtered acceleration norm at the peak (m/s^2, gravity included).
    valley_acc_ms2 : ndarray
        Minimum of the filtered norm between the previous step (or one ``max_interval_s`` back,
        whichever is later) and this peak (m/s^2). ``peak - valley`` feeds the Weinberg model.
    frequency_hz : ndarray
        ``1 / (t_i - t_{i-1})``; the first step of a walking bout (previous step more than
        ``max_interval_s`` ago) takes the next step's interval; NaN for an isolated step.
    prominence_ms2 : ndarray
        Peak prominence of the filtered norm (m/s^2).
    fs_hz : float
        Rate of the uniform grid the detection ran on.
    noise_ms2 : float
        Estimated white-noise standard deviation of the raw norm (m/s^2).
    threshold_ms2 : float
        Absolute prominence threshold that was applied (m/s^2).
    """

    t_ms: NDArray[np.float64]
    peak_acc_ms2: NDArray[np.float64]
    valley_acc_ms2: NDArray[np.float64]
    frequency_hz: NDArray[np.float64]
    prominence_ms2: NDArray[np.float64]
    fs_hz: float
    noise_ms2: float
    threshold_ms2: float

    def __len__(self) -> int:
        return len(self.t_ms)

    @property
    def delta_acc_ms2(self) -> NDArray[np.float64]:
        """``peak - valley`` per step (m/s^2), the Weinberg input."""
        return self.peak_acc_ms2 - self.valley_acc_ms2


def acceleration_magnitude(acc: ArrayLike) -> NDArray[np.float64]:
    """Norm of device-frame acceleration samples.

    Parameters
    ----------
    acc : array_like, shape (n, 3)
        Accelerometer samples (m/s^2, gravity included).

    Returns
    -------
    ndarray, shape (n,)
        ``|a|`` in m/s^2 (about 9.81 at rest).
    """
    a = np.asarray(acc, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ProcessingError(f"acceleration must have shape (n, 3), got {a.shape}")
    return np.linalg.norm(a, axis=1)


def _times_ms(t: ArrayLike, time_unit: str) -> NDArray[np.float64]:
    if time_unit not in ("ms", "s"):
        raise ProcessingError(f"time_unit must be 'ms' or 's', got {time_unit!r}")
    tt = np.asarray(t, dtype=np.float64).ravel()
    return tt * 1000.0 if time_unit == "s" else tt


def _filtered_noise_gain(sos: NDArray[np.float64], fs: float) -> float:
    """Std of zero-phase-filtered unit white noise (|H|^2 applied, forward-backward)."""
    w, h = signal.sosfreqz(sos, worN=4096, fs=fs)
    p = np.abs(h) ** 4
    integral = float(np.sum(0.5 * (p[1:] + p[:-1]) * np.diff(w)))
    return float(np.sqrt(integral / (fs / 2.0)))


def detect_steps(t: ArrayLike, acc: ArrayLike, *, time_unit: Literal["ms", "s"] = "ms",
                 cutoff_hz: float = 3.0, order: int = 4, min_interval_s: float = 0.3,
                 max_interval_s: float = 1.0, min_prominence_ms2: float = 0.5,
                 noise_factor: float = 5.0, activity_factor: float = 2.0,
                 activity_window_s: float = 1.0, relative_prominence: float = 0.35,
                 relative_window_s: float = 4.0, fs_hz: float | None = None) -> Steps:
    """Detect steps in a walk's accelerometer stream.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, non-decreasing (duplicates are dropped, keeping the first), unit
        ``time_unit``. Sampling may be irregular; the norm is linearly resampled.
    acc : array_like, shape (n, 3)
        Device-frame acceleration (m/s^2, gravity included).
    time_unit : {"ms", "s"}
        Unit of ``t``. Step times are always returned in ms.
    cutoff_hz : float
        Low-pass cutoff (Hz); must stay above the fastest step frequency (about 2.5 Hz).
    order : int
        Butterworth order (the forward-backward application doubles the attenuation).
    min_interval_s : float
        Minimum time between two steps (s).
    max_interval_s : float
        Longest step interval still counted as continuous walking (s); used for the frequency and
        the valley search.
    min_prominence_ms2 : float
        Floor of the absolute prominence threshold (m/s^2).
    noise_factor : float
        Threshold in units of the filtered-noise standard deviation. Pure 50 Hz white noise
        through the default filter gives peaks above 5 sigma about 16 times per hour; the
        activity gate removes nearly all of them (0-1 per hour in simulation).
    activity_factor : float
        Minimum moving standard deviation of the filtered norm around a peak, in units of the
        filtered-noise standard deviation (0 = off).
    activity_window_s : float
        Window of that moving standard deviation (s).
    relative_prominence : float
        Minimum prominence relative to the local median prominence of candidate peaks (0 = off).
    relative_window_s : float
        Width of the window for the local median (s).
    fs_hz : float, optional
        Resampling rate (Hz); default the median rate of the input.

    Returns
    -------
    Steps
        Step times (ms), peak/valley acceleration, frequency, prominence; empty arrays when the
        walk contains no step.

    Raises
    ------
    ProcessingError
        Bad shapes, non-finite values, decreasing times, or a stream too short to filter.
    """
    tm = _times_ms(t, time_unit)
    mag = acceleration_magnitude(acc)
    if len(tm) != len(mag):
        raise ProcessingError(f"t ({len(tm)}) and acc ({len(mag)}) differ in length")
    if not (np.all(np.isfinite(tm)) and np.all(np.isfinite(mag))):
        raise ProcessingError("accelerometer times or values contain NaN/inf")
    if np.any(np.diff(tm) < 0):
        raise ProcessingError("accelerometer times must be non-decreasing")
    keep = np.concatenate([[True], np.diff(tm) > 0])
    tm, mag = tm[keep], mag[keep]
    if len(tm) < 4:
        raise ProcessingError(f"accelerometer stream too short ({len(tm)} samples)")
    if tm[-1] - tm[0] > 2 * MAX_FROM_MEDIAN_TIME_MS:  # the time grid would not fit in memory
        raise ProcessingError(f"accelerometer times span {(tm[-1] - tm[0]) / 3.6e6:.3g} h "
                              f"(from {tm[0]:.0f} to {tm[-1]:.0f} ms): a walk's rows lie within "
                              f"{2 * MAX_FROM_MEDIAN_TIME_MS // 3_600_000} h (a wrong clock?)")
    if fs_hz is None:
        fs = 1000.0 / float(np.median(np.diff(tm)))
    else:
        fs = float(fs_hz)
    if not np.isfinite(fs) or fs <= 2.0 * cutoff_hz:
        raise ProcessingError(f"sampling rate {fs:.3g} Hz too low for a {cutoff_hz} Hz low-pass")
    n_grid = int(np.floor((tm[-1] - tm[0]) * fs / 1000.0)) + 1
    grid = tm[0] + np.arange(n_grid) * (1000.0 / fs)
    x = np.interp(grid, tm, mag)
    sos = signal.butter(order, cutoff_hz, btype="low", fs=fs, output="sos")
    padlen = 3 * (2 * len(sos) + 1)
    if n_grid <= padlen:
        raise ProcessingError(f"accelerometer stream too short to filter ({n_grid} samples)")
    xf = signal.sosfiltfilt(sos, x)

    # White-noise level of the raw norm from second differences (the walking signal, below
    # ~5 Hz, contributes little to them at >= 25 Hz sampling); MAD keeps it robust.
    d2 = np.diff(x, 2)
    noise = float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))
    sigma_f = noise * _filtered_noise_gain(sos, fs)
    threshold = max(min_prominence_ms2, noise_factor * sigma_f)

    distance = max(1, int(np.ceil(min_interval_s * fs)))
    wlen = int(np.ceil(2.0 * max_interval_s * fs)) | 1
    peaks, props = signal.find_peaks(xf, distance=distance, prominence=threshold, wlen=wlen)
    prom = props["prominences"]
    if len(peaks) and activity_factor > 0:
        # Activity gate: the filtered norm must vary around the peak (moving standard deviation
        # over activity_window_s) clearly more than filtered noise does.
        half_w = max(1, round(activity_window_s * fs / 2.0))
        c1 = np.concatenate([[0.0], np.cumsum(xf - xf.mean())])
        c2 = np.concatenate([[0.0], np.cumsum((xf - xf.mean()) ** 2)])
        lo_w = np.maximum(peaks - half_w, 0)
        hi_w = np.minimum(peaks + half_w + 1, n_grid)
        k = hi_w - lo_w
        mean_w = (c1[hi_w] - c1[lo_w]) / k
        std_w = np.sqrt(np.maximum((c2[hi_w] - c2[lo_w]) / k - mean_w ** 2, 0.0))
        ok = std_w >= activity_factor * max(sigma_f, 1e-12)
        peaks, prom = peaks[ok], prom[ok]
    if len(peaks) and relative_prominence > 0:
        tp = grid[peaks]
        half = relative_window_s * 1000.0 / 2.0
        lo = np.searchsorted(tp, tp - half, side="left")
        hi = np.searchsorted(tp, tp + half, side="right")
        width = int((hi - lo).max())
        idx = lo[:, None] + np.arange(width)[None, :]
        window = np.where(idx < hi[:, None], prom[np.minimum(idx, len(prom) - 1)], np.nan)
        ref = np.nanmedian(window, axis=1)
        ok = prom >= relative_prominence * ref
        peaks, prom = peaks[ok], prom[ok]

    empty = np.empty(0)
    if len(peaks) == 0:
        return Steps(empty, empty, empty, empty, empty, fs, noise, threshold)

    # Sub-sample peak time by a parabola through the three samples around the peak.
    inner = (peaks > 0) & (peaks < n_grid - 1)
    pc = np.clip(peaks, 1, n_grid - 2)
    y0, y1, y2 = xf[pc - 1], xf[pc], xf[pc + 1]
    den = y0 - 2.0 * y1 + y2
    with np.errstate(invalid="ignore", divide="ignore"):
        off = np.where(inner & (den < 0), 0.5 * (y0 - y2) / den, 0.0)
    off = np.clip(off, -0.5, 0.5)
    t_steps = grid[peaks] + off * (1000.0 / fs)
    peak_acc = xf[peaks]

    # Valley: minimum of the filtered norm since the previous step (at most max_interval back).
    start = np.concatenate([[0], peaks[:-1]])
    start = np.maximum(start, peaks - int(np.ceil(max_interval_s * fs)))
    start = np.maximum(start, 0)
    cmin = _range_min(xf, start, peaks + 1)

    dt = np.diff(t_steps) / 1000.0
    prev = np.concatenate([[np.inf], dt])
    nxt = np.concatenate([dt, [np.inf]])
    freq = np.where(prev <= max_interval_s, 1.0 / prev,
                    np.where(nxt <= max_interval_s, 1.0 / nxt, np.nan))
    return Steps(t_ms=t_steps, peak_acc_ms2=peak_acc, valley_acc_ms2=cmin, frequency_hz=freq,
                 prominence_ms2=prom.astype(np.float64), fs_hz=fs, noise_ms2=noise,
                 threshold_ms2=float(threshold))


def _range_min(x: NDArray[np.float64], lo: NDArray[np.intp],
               hi: NDArray[np.intp]) -> NDArray[np.float64]:
    """``min(x[lo[i]:hi[i]])`` for every i (all ranges non-empty), vectorized."""
    width = int((hi - lo).max())
    idx = lo[:, None] + np.arange(width)[None, :]
    vals = np.where(idx < hi[:, None], x[np.minimum(idx, len(x) - 1)], np.inf)
    return vals.min(axis=1)


def weinberg_length(delta_acc_ms2: ArrayLike, k: float) -> NDArray[np.float64]:
    """Weinberg step length ``L = K * (a_max - a_min)^(1/4)`` (paper 002).

    Parameters
    ----------
    delta_acc_ms2 : array_like, shape (m,)
        Peak-to-valley acceleration swing per step (m/s^2), e.g. :attr:`Steps.delta_acc_ms2`.
        Negative values are clipped to 0.
    k : float
        Weinberg constant (m / (m/s^2)^(1/4)).

    Returns
    -------
    ndarray, shape (m,)
        Step lengths (m).
    """
    d = np.asarray(delta_acc_ms2, dtype=np.float64)
    return k * np.maximum(d, 0.0) ** 0.25


def frequency_length(frequency_hz: ArrayLike, alpha: float, beta: float) -> NDArray[np.float64]:
    """Frequency-linear step length ``L = alpha * f + beta`` (paper 001 eq. 13, 003 eq. 7).

    Parameters
    ----------
    frequency_hz : array_like, shape (m,)
        Step frequency (Hz).
    alpha : float
        Slope (m per Hz, i.e. m*s); NOTES.md range [0.1, 1].
    beta : float
        Offset (m); NOTES.md range [-0.5, 0].

    Returns
    -------
    ndarray, shape (m,)
        Step lengths (m), clipped at 0.
    """
    f = np.asarray(frequency_hz, dtype=np.float64)
    return np.maximum(alpha * f + beta, 0.0)


def turn_corrected_length(length_m: ArrayLike, turn_rad: ArrayLike) -> NDArray[np.float64]:
    """Body displacement of a turning step, ``L * sin((pi - theta) / 2)`` (paper 001 eq. 14).

    Parameters
    ----------
    length_m : array_like, shape (m,)
        Step length (m).
    turn_rad : array_like, shape (m,)
        Heading change over the step (rad); the sign does not matter.

    Returns
    -------
    ndarray, shape (m,)
        Corrected lengths (m): unchanged for 0, ``L / sqrt(2)`` for a 90 deg turn.
    """
    th = np.abs(np.asarray(turn_rad, dtype=np.float64))
    return np.asarray(length_m, dtype=np.float64) * np.sin((np.pi - th) / 2.0)


def segment_ids(step_t_ms: ArrayLike, waypoint_t_ms: ArrayLike) -> NDArray[np.intp]:
    """Which waypoint leg each step belongs to.

    Parameters
    ----------
    step_t_ms : array_like, shape (m,)
        Step times (ms).
    waypoint_t_ms : array_like, shape (k,)
        Waypoint click times (ms), increasing. Leg ``j`` is ``[t_j, t_{j+1})``.

    Returns
    -------
    ndarray of int, shape (m,)
        Leg index in ``0 .. k-2``, or -1 for steps before the first or after the last waypoint.
    """
    ts = np.asarray(step_t_ms, dtype=np.float64).ravel()
    tw = np.asarray(waypoint_t_ms, dtype=np.float64).ravel()
    if len(tw) >= 2 and np.any(np.diff(tw) <= 0):
        raise ProcessingError("waypoint times must be strictly increasing")
    j = np.searchsorted(tw, ts, side="right") - 1
    return np.where((j >= 0) & (j <= len(tw) - 2), j, -1).astype(np.intp)


@dataclass(frozen=True)
class StepLengthFit:
    """A fitted step-length model.

    Attributes
    ----------
    model : str
        ``"weinberg"`` (params ``(k,)``) or ``"frequency"`` (params ``(alpha, beta)``).
    params : tuple of float
        Fitted parameters, units as in :func:`weinberg_length` / :func:`frequency_length`.
    at_bound : tuple of bool
        Per parameter, whether it ended on a bound (the data wanted a value outside the range).
    residuals_m : ndarray, shape (n_seg,)
        Per leg, model distance minus waypoint distance (m); NaN for legs not used.
    residual_rms_m : float
        RMS of the used legs' residuals (m).
    n_segments : int
        Legs used (at least one step and a finite distance).
    n_steps : int
        Steps inside the used legs.
    """

    model: str
    params: tuple[float, ...]
    at_bound: tuple[bool, ...]
    residuals_m: NDArray[np.float64]
    residual_rms_m: float
    n_segments: int
    n_steps: int

    def step_lengths(self, x: ArrayLike) -> NDArray[np.float64]:
        """Step lengths (m) from the model input (``delta_acc_ms2`` or ``frequency_hz``)."""
        if self.model == "weinberg":
            return weinberg_length(x, self.params[0])
        return frequency_length(x, self.params[0], self.params[1])


def _leg_sums(features: NDArray[np.float64], seg: NDArray[np.intp],
              distance: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                      NDArray[np.bool_]]:
    """Per-leg sums of each feature column and step counts; mask of usable legs."""
    n_seg = len(distance)
    inside = (seg >= 0) & (seg < n_seg)
    sums = np.zeros((n_seg, features.shape[1]))
    np.add.at(sums, seg[inside], features[inside])
    counts = np.bincount(seg[inside], minlength=n_seg).astype(np.float64)
    usable = (counts > 0) & np.isfinite(distance) & (distance >= 0)
    return sums, counts, usable


def _fit_linear(design: NDArray[np.float64], target: NDArray[np.float64], x0: NDArray[np.float64],
                lower: NDArray[np.float64], upper: NDArray[np.float64], loss: str,
                f_scale_m: float) -> NDArray[np.float64]:
    inner = lower + 1e-9 * np.maximum(upper - lower, 1.0)
    outer = upper - 1e-9 * np.maximum(upper - lower, 1.0)
    x0 = np.minimum(np.maximum(x0, inner), outer)  # least_squares wants x0 strictly inside
    res = optimize.least_squares(lambda p: design @ p - target, x0, bounds=(lower, upper),
                                 loss=loss, f_scale=f_scale_m, method="trf")
    return res.x


def _check_inputs(x: ArrayLike, segment_id: ArrayLike, segment_distance_m: ArrayLike,
                  name: str) -> tuple[NDArray[np.float64], NDArray[np.intp], NDArray[np.float64]]:
    xv = np.asarray(x, dtype=np.float64).ravel()
    seg = np.asarray(segment_id).ravel()
    if not np.issubdtype(seg.dtype, np.integer):
        raise ProcessingError("segment_id must be integers")
    dist = np.asarray(segment_distance_m, dtype=np.float64).ravel()
    if len(xv) != len(seg):
        raise ProcessingError(f"{name} ({len(xv)}) and segment_id ({len(seg)}) differ in length")
    return xv, seg.astype(np.intp), dist


def _finish(model: str, params: NDArray[np.float64], lower: NDArray[np.float64],
            upper: NDArray[np.float64], pred: NDArray[np.float64], dist: NDArray[np.float64],
            usable: NDArray[np.bool_], counts: NDArray[np.float64]) -> StepLengthFit:
    resid = np.where(usable, pred - dist, np.nan)
    span = upper - lower
    tol = 1e-6 * np.where(np.isfinite(span), span, 1.0)
    at_bound = tuple(bool(b) for b in (np.abs(params - lower) <= tol) |
                     (np.abs(params - upper) <= tol))
    return StepLengthFit(model=model, params=tuple(float(p) for p in params), at_bound=at_bound,
                         residuals_m=resid,
                         residual_rms_m=float(np.sqrt(np.mean(resid[usable] ** 2))),
                         n_segments=int(usable.sum()), n_steps=int(counts[usable].sum()))


def fit_weinberg(delta_acc_ms2: ArrayLike, segment_id: ArrayLike, segment_distance_m: ArrayLike,
                 *, k_bounds: tuple[float, float] = (0.1, 1.5), loss: str = "soft_l1",
                 f_scale_m: float = 0.5) -> StepLengthFit:
    """Fit the Weinberg constant K to waypoint legs.

    Minimizes ``sum_j rho(K * sum_{i in leg j} (a_max - a_min)_i^(1/4) - D_j)`` over K within
    ``k_bounds``, ``rho`` a robust loss (scipy ``least_squares``), so that a few legs with a
    mis-clicked waypoint do not drag the fit.

    Parameters
    ----------
    delta_acc_ms2 : array_like, shape (m,)
        Peak-to-valley swing per step (m/s^2).
    segment_id : array_like of int, shape (m,)
        Leg of each step (from :func:`segment_ids`), -1 for none.
    segment_distance_m : array_like, shape (n_seg,)
        Distance between the leg's waypoints (m); NaN marks a leg to skip.
    k_bounds : (float, float)
        Bounds on K.
    loss : str
        ``least_squares`` loss: ``"linear"``, ``"soft_l1"``, ``"huber"``, ``"cauchy"``...
    f_scale_m : float
        Residual scale (m) where the robust loss starts to flatten.

    Returns
    -------
    StepLengthFit
        ``model="weinberg"``, ``params=(K,)``.

    Raises
    ------
    ProcessingError
        No leg with steps and a finite distance.
    """
    d, seg, dist = _check_inputs(delta_acc_ms2, segment_id, segment_distance_m, "delta_acc_ms2")
    feat = np.maximum(np.nan_to_num(d, nan=0.0), 0.0) ** 0.25
    sums, counts, usable = _leg_sums(feat[:, None], seg, dist)
    if not usable.any():
        raise ProcessingError("no waypoint leg with steps and a distance to fit step length")
    lower, upper = np.array([k_bounds[0]]), np.array([k_bounds[1]])
    x0 = np.clip([np.sum(dist[usable]) / max(np.sum(sums[usable, 0]), 1e-12)], lower, upper)
    p = _fit_linear(sums[usable], dist[usable], x0, lower, upper, loss, f_scale_m)
    return _finish("weinberg", p, lower, upper, sums @ p, dist, usable, counts)


def fit_frequency_model(frequency_hz: ArrayLike, segment_id: ArrayLike,
                        segment_distance_m: ArrayLike, *,
                        alpha_bounds: tuple[float, float] = (0.1, 1.0),
                        beta_bounds: tuple[float, float] = (-0.5, 0.0), loss: str = "soft_l1",
                        f_scale_m: float = 0.5) -> StepLengthFit:
    """Fit ``L = alpha * f + beta`` to waypoint legs.

    Minimizes ``sum_j rho(alpha * sum_{i in j} f_i + beta * n_j - D_j)`` within the bounds
    (defaults from NOTES.md: alpha in [0.1, 1], beta in [-0.5, 0]). Steps with unknown frequency
    (NaN) take the median frequency of the others so that leg sums still count every step. Alpha
    and beta are only separable when legs are walked at different paces; otherwise the bounds
    and the robust loss pick one of the near-equivalent pairs, with the same leg sums.

    Parameters
    ----------
    frequency_hz : array_like, shape (m,)
        Step frequency (Hz), e.g. :attr:`Steps.frequency_hz`.
    segment_id : array_like of int, shape (m,)
        Leg of each step, -1 for none.
    segment_distance_m : array_like, shape (n_seg,)
        Waypoint distance per leg (m); NaN skips the leg.
    alpha_bounds, beta_bounds : (float, float)
        Parameter bounds (m*s, m).
    loss, f_scale_m :
        As in :func:`fit_weinberg`.

    Returns
    -------
    StepLengthFit
        ``model="frequency"``, ``params=(alpha, beta)``.

    Raises
    ------
    ProcessingError
        No usable leg, or no step with a known frequency.
    """
    f, seg, dist = _check_inputs(frequency_hz, segment_id, segment_distance_m, "frequency_hz")
    known = np.isfinite(f)
    if not known.any():
        raise ProcessingError("no step with a known frequency")
    f = np.where(known, f, np.median(f[known]))
    sums, counts, usable = _leg_sums(np.column_stack([f, np.ones_like(f)]), seg, dist)
    if not usable.any():
        raise ProcessingError("no waypoint leg with steps and a distance to fit step length")
    lower = np.array([alpha_bounds[0], beta_bounds[0]])
    upper = np.array([alpha_bounds[1], beta_bounds[1]])
    x0 = np.clip(np.array([0.35, -0.05]), lower, upper)
    p = _fit_linear(sums[usable], dist[usable], x0, lower, upper, loss, f_scale_m)
    return _finish("frequency", p, lower, upper, sums @ p, dist, usable, counts)
