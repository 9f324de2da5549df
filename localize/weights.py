"""Weight-update arithmetic: field deltas, per-step error terms, mass-centered coefficients,
Gaussian log-likelihoods and DTW distances.

The mass-centered update (paper 000 eq. b and eq. 5; 001 eqs. 4-12) compares, per particle
``i`` and step ``t``, the magnitude of the map's field change along the particle's last move
with the magnitude of the observed change::

    term_i(t) = | |s_i(t) - s_i(t-1)| - |s_obs(t) - s_obs(t-1)| |
    MMSE_i(t) = mean of term_i over the last W steps
    c_i       = K / max(MMSE_i(t), T)

A term is computed once, when its step happens, and then travels with its particle through
resampling; a window mean is a sum over ``W`` stored terms (``O(W N)`` per step, as the paper's
complexity analysis states). Arrays are ``(u, n)`` (users x particles) or ``(h, u, n)``
histories, oldest first.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["dtw_distance", "mass_centered_coefficient", "newest_delta", "term_gaussian",
           "term_mass_centered", "window_mean", "window_sum"]


def newest_delta(vals: NDArray, span: int, smooth: int, angle: bool) -> NDArray:
    """The newest delta ``S(t) - S(t - span)`` of a value history, ``S`` the moving average of
    ``smooth`` values.

    Parameters
    ----------
    vals : ndarray, shape (span + smooth, ...)
        Values, oldest first (feature unit; NaN = unknown).
    span, smooth : int
    angle : bool
        Degrees that wrap: values are unwrapped around the newest one, the delta wrapped to
        [-180, 180).

    Returns
    -------
    ndarray, shape vals.shape[1:]
    """
    if smooth == 1 and span == 1 and len(vals) == 2:
        d = vals[1] - vals[0]
    else:
        if angle:
            vals = vals[-1] + ((vals - vals[-1] + 180.0) % 360.0 - 180.0)
        new = vals[-smooth:].mean(axis=0) if smooth > 1 else vals[-1]
        old = vals[-smooth - span:len(vals) - span]
        old = old.mean(axis=0) if smooth > 1 else old[-1]
        d = new - old
    if angle:
        d = (d + 180.0) % 360.0 - 180.0
    return d


def term_mass_centered(d_map: NDArray, d_obs: NDArray) -> NDArray:
    """``| |d_map| - |d_obs| |`` (000 eq. b): the per-step term of MMSE/MMAE/MMPE.

    ``d_map`` (u, n), ``d_obs`` (u,) or (u, 1); NaN where either is unknown.
    """
    return np.abs(np.abs(d_map) - np.abs(np.asarray(d_obs).reshape(-1, 1)))


def term_gaussian(d_map: NDArray, d_obs: NDArray) -> NDArray:
    """``(d_map - d_obs)^2``: the per-step term of a Gaussian likelihood of signed deltas."""
    e = d_map - np.asarray(d_obs).reshape(-1, 1)
    return e * e


def window_mean(terms: NDArray) -> NDArray[np.float64]:
    """Mean of the known terms over the window axis 0 (NaN where none is known)."""
    if np.isfinite(terms).all():
        return terms.mean(axis=0)
    known = np.isfinite(terms)
    cnt = known.sum(axis=0)
    tot = np.where(known, terms, 0.0).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, tot / cnt, np.nan)


def window_sum(terms: NDArray) -> NDArray[np.float64]:
    """Sum of the known terms over axis 0 (NaN where none is known)."""
    known = np.isfinite(terms)
    tot = np.where(known, terms, 0.0).sum(axis=0)
    return np.where(known.any(axis=0), tot, np.nan)


def mass_centered_coefficient(err: NDArray[np.float64], award: float,
                              threshold: float | NDArray) -> NDArray[np.float64]:
    """``c = K / max(err, T)`` (000 eq. 5; 001 eqs. 8-10), per particle.

    Particles without a known error get the smallest coefficient of their user (as bad as the
    worst known particle); a user with no known error at all gets ``c = 1`` (no update).

    Parameters
    ----------
    err : ndarray, shape (u, n)
        Mean delta error (NaN = unknown).
    award : float
        K.
    threshold : float or ndarray broadcastable to (u, n)
        T (feature unit).

    Returns
    -------
    ndarray, shape (u, n), positive

    Examples
    --------
    >>> mass_centered_coefficient(np.array([[0.01, 0.5, np.nan]]), 70.0, 0.05).tolist()
    [[1400.0, 140.0, 140.0]]
    """
    c = award / np.maximum(err, threshold)
    known = np.isfinite(c)
    if known.all():
        return c
    worst = np.min(np.where(known, c, np.inf), axis=1, keepdims=True)
    worst = np.where(np.isfinite(worst), worst, 1.0)
    return np.where(known, c, worst)


def dtw_distance(obs: NDArray[np.float64], ref: NDArray[np.float64]) -> NDArray[np.float64]:
    """Dynamic time warping distance between one observed sequence and many references.

    Anti-diagonal (wavefront) evaluation of ``D[i, j] = |obs[i] - ref[:, j]| + min(D[i-1, j],
    D[i, j-1], D[i-1, j-1])``, vectorized over references: ``O(P m k)`` work in
    ``m + k - 1`` numpy passes (Magicol's per-particle matching).

    Parameters
    ----------
    obs : ndarray, shape (m,)
    ref : ndarray, shape (P, k)

    Returns
    -------
    ndarray, shape (P,)
        ``D[m-1, k-1]``; NaN where a reference value is NaN.
    """
    obs = np.asarray(obs, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    m, (p, k) = len(obs), ref.shape
    # Three rotating anti-diagonal buffers indexed by row i + 1 (column 0 stays inf, so the
    # i - 1 neighbours of row 0 need no special case).
    buf = np.full((3, p, m + 1), np.inf)
    buf[0, :, 1] = np.abs(obs[0] - ref[:, 0])
    for s in range(1, m + k - 1):
        lo, hi = max(0, s - k + 1), min(s, m - 1)
        prev1, prev2, cur = buf[(s - 1) % 3], buf[(s - 2) % 3], buf[s % 3]
        cost = np.abs(obs[lo:hi + 1][None, :] - ref[:, s - hi:s - lo + 1][:, ::-1])
        best = np.minimum(prev1[:, lo + 1:hi + 2], prev1[:, lo:hi + 1])  # D[i,j-1], D[i-1,j]
        np.minimum(best, prev2[:, lo:hi + 1], out=best)                  # D[i-1,j-1]
        cur[:] = np.inf
        np.add(cost, best, out=cur[:, lo + 1:hi + 2])
    return buf[(m + k - 2) % 3][:, m]
