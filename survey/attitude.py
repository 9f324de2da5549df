"""Per-step phone attitude from the accelerometer (paper 001, Algorithm 2 and Tables 2-4).

For every step the classifier looks at the step cycle (from the previous step to this one) and
the stride (this cycle and its neighbour, two steps), in the device frame (x right, y top edge,
z out of the screen; specific force, so a phone lying screen up reads ``+g`` on z):

1. *Upward*: mean ``a_z`` over the stride ``> k1 * g``; otherwise :attr:`Attitude.NOT_UPWARD`.
2. *Upward forward (UF)*, from three feature events:

   * E1 -- the peak of the (low-passed) y acceleration lies in the latter half of the step cycle
     (forward push peaks just before the vertical peak that ends the cycle);
   * E2 -- mean ``a_y`` over the stride exceeds mean ``a_x`` (the screen is tilted a little
     towards the eyes, so part of gravity falls on +y);
   * E3 -- the x acceleration alternates from step to step (lateral sway has the period of a
     stride): the cycle mean of ``a_x`` is above both neighbouring cycles' means or below both,
     and the alternation amplitude over five cycles is at least ``e3_margin_ms2``.

   ``P(UF | E1, E2, E3)`` comes from the paper's Table 4 (equation 1 with equal priors); the phone
   is UF when it exceeds 50 %, which happens exactly for E1E2E3 and (not E1)E2E3. Otherwise the
   step is :attr:`Attitude.UNF` (upward, not forward: held sideways or backwards).
3. *Horizontal*: incline ``theta = atan(sum a_y / sum a_z)`` over the stride (equation 2);
   :attr:`Attitude.UFH` when ``|theta| < k2 * 90 deg``, else :attr:`Attitude.UFNH`.

Algorithm 2 prints "NUF" for both failures (not upward; upward but not forward); like the
paper's Figure 15 this module keeps them apart as NOT_UPWARD and UNF.

Parameters the paper does not state (chosen here, documented in :class:`AttitudeParams`):
``k1 = 0.4`` (upward while the screen normal is within ~66 deg of vertical, so a phone tilted
60 deg towards the eyes is still upward but a phone in a trouser pocket or at the ear, with z
roughly horizontal, is not), ``k2 = 0.25`` (horizontal below 22.5 deg: the ILC surveyors hold the
phone within ~7 deg of flat, a reading posture tilted 30-60 deg is UFNH), the E3 margin and the
E1 low-pass. A phone lying exactly flat makes E2 a coin toss (mean a_y ~ mean a_x ~ 0); the
optional ``e2_margin_ms2`` relaxes E2 to ``mean a_y > mean a_x - margin`` for such data.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal

from survey.errors import ProcessingError
from survey.steps import STANDARD_GRAVITY

__all__ = ["Attitude", "AttitudeParams", "StepAttitudes", "classify_attitude",
           "p_upward_forward"]


class Attitude(str, Enum):
    """Phone attitude of one step (string valued, so arrays of codes compare with strings)."""

    #: Upward, forward, horizontal: screen up, top edge forward, screen near horizontal.
    UFH = "UFH"
    #: Upward, forward, not horizontal (e.g. tilted towards the eyes by more than k2 * 90 deg).
    UFNH = "UFNH"
    #: Upward but not forward (top edge pointing left, right or back).
    UNF = "UNF"
    #: Screen not facing up (pocket, at the ear, upside down, swinging hand).
    NOT_UPWARD = "NU"
    #: Too few samples in the step cycle to decide.
    UNKNOWN = "UNKNOWN"

    def __str__(self) -> str:  # the code, so numpy and f-strings see "UFH", not "Attitude.UFH"
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)


#: Paper 001 Table 4: P(UF | E1, E2, E3), keyed by (E1, E2, E3).
_TABLE4: dict[tuple[bool, bool, bool], float] = {
    (True, True, True): 1.00,
    (False, True, True): 1.00,
    (True, False, True): 0.00,
    (True, True, False): 0.0633,
    (False, True, False): 0.00,
    (False, False, True): 0.00,
    (True, False, False): 0.00,
    (False, False, False): 0.00,
}


def p_upward_forward(e1: ArrayLike, e2: ArrayLike, e3: ArrayLike) -> NDArray[np.float64]:
    """Posterior probability of the UF attitude given the feature events (paper 001, Table 4).

    Parameters
    ----------
    e1, e2, e3 : array_like of bool, shape (m,)
        Feature events per step.

    Returns
    -------
    ndarray, shape (m,)
        ``P(UF | E1, E2, E3)`` in [0, 1].
    """
    b1, b2, b3 = (np.asarray(e, dtype=bool) for e in (e1, e2, e3))
    code = b1.astype(int) * 4 + b2.astype(int) * 2 + b3.astype(int)
    lut = np.zeros(8)
    for (k1, k2, k3), p in _TABLE4.items():
        lut[int(k1) * 4 + int(k2) * 2 + int(k3)] = p
    return lut[code]


@dataclass(frozen=True)
class AttitudeParams:
    """Thresholds of the attitude classifier.

    Attributes
    ----------
    k1 : float
        Upward when the stride-mean ``a_z > k1 * g`` (paper symbol; value chosen here: 0.4).
    k2 : float
        Horizontal when ``|theta| < k2 * 90 deg`` (paper symbol; value chosen here: 0.25,
        i.e. 22.5 deg).
    g_ms2 : float
        Gravity (m/s^2).
    e2_margin_ms2 : float
        E2 holds when ``mean a_y > mean a_x - e2_margin_ms2``; 0 is the paper's rule.
    e3_margin_ms2 : float
        Minimum amplitude (m/s^2) of the step-to-step alternation of the cycle-mean ``a_x``
        for E3 (a sway of amplitude L gives cycle means of about +-2L/pi); keeps noise and slow
        hand wobble from faking alternation.
    max_cycle_s : float
        A step cycle starts at most this long before its step (the first step after a pause).
    min_samples : int
        Cycles with fewer samples are UNKNOWN.
    lowpass_hz : float
        Low-pass (zero-phase Butterworth, 4th order) applied to a_y before locating its peak
        for E1.
    """

    k1: float = 0.4
    k2: float = 0.25
    g_ms2: float = STANDARD_GRAVITY
    e2_margin_ms2: float = 0.0
    e3_margin_ms2: float = 0.15
    max_cycle_s: float = 1.0
    min_samples: int = 5
    lowpass_hz: float = 5.0


@dataclass(frozen=True)
class StepAttitudes:
    """Attitude and its evidence per step; every array has shape (m,).

    Attributes
    ----------
    step_t_ms : ndarray
        The step times that were classified (ms).
    attitude : ndarray of str
        :class:`Attitude` values (``"UFH"``, ``"UFNH"``, ``"UNF"``, ``"NU"``, ``"UNKNOWN"``).
    mean_az_ms2 : ndarray
        Stride-mean z acceleration (m/s^2).
    theta_deg : ndarray
        Incline ``atan2(sum a_y, sum a_z)`` over the stride (deg, paper eq. 2).
    e1, e2, e3 : ndarray of bool
        Feature events.
    p_uf : ndarray
        Table-4 probability of the UF attitude.
    """

    step_t_ms: NDArray[np.float64]
    attitude: NDArray[np.str_]
    mean_az_ms2: NDArray[np.float64]
    theta_deg: NDArray[np.float64]
    e1: NDArray[np.bool_]
    e2: NDArray[np.bool_]
    e3: NDArray[np.bool_]
    p_uf: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.step_t_ms)


def _lowpass(t_ms: NDArray[np.float64], x: NDArray[np.float64], cutoff_hz: float) -> NDArray:
    """Zero-phase low-pass assuming near-uniform sampling; unfiltered when impossible."""
    if len(t_ms) < 2:
        return x
    fs = 1000.0 / float(np.median(np.diff(t_ms)))
    if not np.isfinite(fs) or fs <= 2.5 * cutoff_hz:
        return x
    sos = signal.butter(4, cutoff_hz, btype="low", fs=fs, output="sos")
    if len(x) <= 3 * (2 * len(sos) + 1):
        return x
    return signal.sosfiltfilt(sos, x)


def _alternation(xc: NDArray[np.float64], margin: float) -> NDArray[np.bool_]:
    """E3 per cycle from the cycle means ``xc`` (m,) of a_x; ends copy the nearest inner cycle."""
    m = len(xc)
    e3 = np.zeros(m, dtype=bool)
    if m < 3:
        return e3
    mid, left, right = xc[1:-1], xc[:-2], xc[2:]
    extreme = np.zeros(m, dtype=bool)
    extreme[1:-1] = (mid - left) * (mid - right) > 0
    extreme[0], extreme[-1] = extreme[1], extreme[-2]
    amp = np.full(m, np.nan)
    if m >= 5:
        amp[2:-2] = np.abs(-xc[:-4] + 4 * xc[1:-3] - 6 * xc[2:-2] + 4 * xc[3:-1] - xc[4:]) / 16
        amp[:2], amp[-2:] = amp[2], amp[-3]
    else:
        amp[1:-1] = np.abs(mid - 0.5 * (left + right))
        amp[0], amp[-1] = amp[1], amp[-2]
    e3 = extreme & (amp >= margin)
    return e3 & np.isfinite(xc)


def classify_attitude(t_ms: ArrayLike, acc: ArrayLike, step_t_ms: ArrayLike,
                      params: AttitudeParams | None = None) -> StepAttitudes:
    """Classify the phone attitude of every step (paper 001, Algorithm 2).

    Parameters
    ----------
    t_ms : array_like, shape (n,)
        Accelerometer sample times (ms), non-decreasing.
    acc : array_like, shape (n, 3)
        Device-frame acceleration (m/s^2, gravity included).
    step_t_ms : array_like, shape (m,)
        Step times (ms), increasing, e.g. :attr:`survey.steps.Steps.t_ms`. Step ``i`` covers
        the cycle ``(t_{i-1}, t_i]`` (the first step: one next-step interval back), at most
        ``params.max_cycle_s`` long.
    params : AttitudeParams, optional
        Thresholds; defaults documented in :class:`AttitudeParams`.

    Returns
    -------
    StepAttitudes
        Per-step attitude codes and the evidence behind them.

    Raises
    ------
    ProcessingError
        Bad shapes, non-finite values or unsorted times.
    """
    p = params or AttitudeParams()
    t = np.asarray(t_ms, dtype=np.float64).ravel()
    a = np.asarray(acc, dtype=np.float64)
    s = np.asarray(step_t_ms, dtype=np.float64).ravel()
    if a.ndim != 2 or a.shape[1] != 3 or len(a) != len(t):
        raise ProcessingError(f"acc must have shape ({len(t)}, 3), got {a.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(a)) and np.all(np.isfinite(s))):
        raise ProcessingError("attitude input contains NaN/inf")
    if np.any(np.diff(t) < 0) or np.any(np.diff(s) <= 0):
        raise ProcessingError("sample times must be non-decreasing and step times increasing")
    m = len(s)
    if m == 0:
        e = np.empty(0)
        return StepAttitudes(e, np.empty(0, dtype="<U7"), e, e, e.astype(bool), e.astype(bool),
                             e.astype(bool), e)

    # Cycle bounds (start, end] per step.
    first = s[1] - s[0] if m >= 2 else p.max_cycle_s * 1000.0
    prev = np.concatenate([[s[0] - first], s[:-1]])
    start = np.maximum(prev, s - p.max_cycle_s * 1000.0)
    lo = np.searchsorted(t, start, side="right")
    hi = np.searchsorted(t, s, side="right")
    cnt = (hi - lo).astype(np.float64)

    csum = np.vstack([np.zeros((1, 3)), np.cumsum(a, axis=0)])
    sums = csum[hi] - csum[lo]                                   # (m, 3) per cycle
    with np.errstate(invalid="ignore", divide="ignore"):
        cmean = sums / cnt[:, None]

    # Stride = this cycle and the previous one (the next one for the first step).
    nb = np.concatenate([[1], np.arange(m - 1)]) if m >= 2 else np.zeros(1, dtype=int)
    ssum = sums + sums[nb] if m >= 2 else sums
    scnt = cnt + cnt[nb] if m >= 2 else cnt
    with np.errstate(invalid="ignore", divide="ignore"):
        smean = ssum / scnt[:, None]
    mean_az = smean[:, 2]
    theta = np.degrees(np.arctan2(ssum[:, 1], ssum[:, 2]))

    # E1: y peak in the latter half of the cycle.
    ay = _lowpass(t, a[:, 1], p.lowpass_hz)
    width = int(max(cnt.max(), 1))
    idx = lo[:, None] + np.arange(width)[None, :]
    inside = idx < hi[:, None]
    idxc = np.minimum(idx, len(t) - 1)
    yv = np.where(inside, ay[idxc], -np.inf)
    kmax = np.argmax(yv, axis=1)
    t_peak = t[np.minimum(lo + kmax, len(t) - 1)]
    dur = s - start
    with np.errstate(invalid="ignore", divide="ignore"):
        e1 = (cnt > 0) & ((t_peak - start) / dur > 0.5)

    # E2: stride mean a_y above stride mean a_x.
    e2 = smean[:, 1] > smean[:, 0] - p.e2_margin_ms2

    # E3: cycle-mean a_x is a local extreme (above or below both neighbours) and the
    # step-to-step alternation is significant: its amplitude, estimated by the 5-point fourth
    # difference (-1, 4, -6, 4, -1) / 16 (exact for a +-A pattern, blind to slow drift of the
    # mean up to a cubic, e.g. hand wobble), is at least e3_margin_ms2.
    e3 = _alternation(cmean[:, 0], p.e3_margin_ms2)

    p_uf = p_upward_forward(e1, e2, e3)
    upward = mean_az > p.k1 * p.g_ms2
    horizontal = np.abs(theta) < p.k2 * 90.0
    att = np.where(~upward, Attitude.NOT_UPWARD.value,
                   np.where(p_uf <= 0.5, Attitude.UNF.value,
                            np.where(horizontal, Attitude.UFH.value, Attitude.UFNH.value)))
    att = np.where(cnt < p.min_samples, Attitude.UNKNOWN.value, att).astype("<U7")
    return StepAttitudes(step_t_ms=s, attitude=att, mean_az_ms2=mean_az, theta_deg=theta,
                         e1=e1, e2=e2, e3=e3, p_uf=p_uf)
