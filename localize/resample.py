"""Systematic resampling (paper 001, Algorithm 1 line 15; Kitagawa 1996), one or many rows.

Weights need not sum to 1: positions ``(u + k) / n`` are scaled by the total
(``np.searchsorted(cumsum, u * cumsum[-1])``, as scikit-learn's ``KernelDensity.sample``), so a
particle is drawn ``floor(n w_i / W)`` or ``ceil(n w_i / W)`` times, and a particle of weight 0
never. Randomness comes only from the injected generator.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.errors import LocalizationError

__all__ = ["check_weights", "effective_sample_size", "systematic_resample",
           "systematic_resample_rows"]


def check_weights(weights: ArrayLike) -> NDArray[np.float64]:
    """Validate particle weights: finite, non-negative, positive sum per row.

    Parameters
    ----------
    weights : array_like, shape (n,) or (u, n)

    Returns
    -------
    ndarray of float64, same shape

    Raises
    ------
    LocalizationError
        Empty, NaN/inf, negative weights, or a row summing to zero.
    """
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim not in (1, 2) or w.shape[-1] == 0:
        raise LocalizationError(f"weights must be a non-empty (n,) or (u, n) array, got shape "
                                f"{w.shape}")
    if not np.all(np.isfinite(w)):
        raise LocalizationError("weights contain NaN or infinite values")
    if np.any(w < 0):
        raise LocalizationError(f"weights must be non-negative (min {w.min():.3g})")
    total = w.sum(axis=-1)
    if np.any(total <= 0) or not np.all(np.isfinite(total)):
        raise LocalizationError("weights must have a positive, finite sum")
    return w


def systematic_resample(weights: ArrayLike, rng: np.random.Generator,
                        n: int | None = None) -> NDArray[np.intp]:
    """Indexes of a systematic resample.

    Parameters
    ----------
    weights : array_like, shape (m,)
        Non-negative particle weights with a positive sum (any scale).
    rng : numpy.random.Generator
        Source of the one uniform offset.
    n : int, optional
        Number of draws (default ``m``).

    Returns
    -------
    ndarray of intp, shape (n,)
        Sorted indexes into ``weights``; index ``i`` appears ``floor(n w_i / sum w)`` or
        ``ceil(...)`` times, never for ``w_i = 0``.

    Raises
    ------
    LocalizationError
        See :func:`check_weights`.

    Examples
    --------
    >>> systematic_resample([0.0, 1.0, 3.0], np.random.default_rng(0)).tolist()
    [1, 2, 2]
    """
    w = check_weights(weights)
    if w.ndim != 1:
        raise LocalizationError("systematic_resample takes one row of weights; use "
                                "systematic_resample_rows for many")
    m = len(w)
    n = m if n is None else int(n)
    cs = np.cumsum(w / w.max())  # scaled: subnormal weights would round in u * total
    u = (rng.random() + np.arange(n)) / n
    idx = np.searchsorted(cs, u * cs[-1], side="right")
    last = int(np.flatnonzero(w > 0)[-1])  # rounding can push a draw past the last weight
    return np.minimum(idx, last)


def systematic_resample_rows(weights: ArrayLike, rng: np.random.Generator,
                             n_out: int | None = None) -> NDArray[np.intp]:
    """Systematic resampling of many independent rows at once (the multi-user engine).

    With positions ``p_k = (u + k) / n`` (one uniform ``u`` per row) particle ``i`` is drawn
    once for every ``p_k`` in ``[C_{i-1}, C_i)``, ``C`` the normalised cumulative weights: the
    same draws as :func:`systematic_resample`, counted in closed form
    (``#{k : p_k < c} = ceil(c n - u)``) instead of searched, so that all rows take a few
    linear passes.

    Parameters
    ----------
    weights : array_like, shape (u, n)
        One row of non-negative weights with a positive sum per user.
    rng : numpy.random.Generator
        One uniform offset is drawn per row.
    n_out : int, optional
        Draws per row (default n): fewer to shrink the particle set, more to grow it.

    Returns
    -------
    ndarray of intp, shape (u, n_out)
        Sorted column indexes per row.
    """
    w = check_weights(weights)
    if w.ndim == 1:
        w = w[None, :]
    u_rows, n = w.shape
    m = n if n_out is None else int(n_out)
    cs = np.cumsum(w / w.max(axis=1, keepdims=True), axis=1)  # no subnormal totals
    scaled = cs * (m / cs[:, -1:])
    below = np.ceil(scaled - rng.random((u_rows, 1)))
    np.clip(below, 0, m, out=below)
    below[:, -1] = m  # exact: every position lies below the total
    counts = np.diff(below, axis=1, prepend=0.0).astype(np.intp)
    counts[w <= 0] = 0  # rounding cannot hand a draw to a zero weight
    fix = m - counts.sum(axis=1)
    if np.any(fix):  # only after the zero-weight guard moved a draw: give it to the heaviest
        counts[np.arange(u_rows), np.argmax(w, axis=1)] += fix
    flat = np.repeat(np.arange(u_rows * n, dtype=np.intp), counts.ravel())
    return (flat - (np.arange(u_rows) * n).repeat(m)).reshape(u_rows, m)


def effective_sample_size(weights: ArrayLike) -> NDArray[np.float64] | float:
    """``N_eff = (sum w)^2 / sum w^2`` per row (paper 002's resampling trigger)."""
    w = np.asarray(weights, dtype=np.float64)
    s = w.sum(axis=-1)
    q = (w * w).sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(q > 0, s * s / q, 0.0)
    return float(out) if np.ndim(out) == 0 else out
