"""Apply weight updates to a :class:`~localize.particles.ParticleState` (users x particles).

The magnetic update is chosen by ``FilterParams.weight_mode``:

- ``"mass_centered"``: ``w *= cs * (ca * cp)^[attitude == UFH]`` (001 eq. 12) with each
  coefficient ``K / max(err, T)`` of its feature's mean delta error (000 eq. 5);
- ``"gaussian"``: ``w *= exp(log L)`` of the signed strength deltas (002-style Gaussian);
- ``"dtw"``: ``w *= exp(-D / (m sigma))`` with ``D`` the DTW distance between the step's raw
  magnetometer strengths and the map along each particle's move (Magicol);
- ``"none"``: no magnetic update (PDR + map constraints).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from localize.maps import FilterMap
from localize.params import FilterParams
from localize.particles import FEATURES, ParticleState
from localize.radio import RadioModel
from localize.steps import AttitudeCode, RadioScan
from localize.weights import (
    dtw_distance,
    mass_centered_coefficient,
    window_mean,
    window_sum,
)

__all__ = ["dtw_update", "gaussian_update", "magnetic_update", "mass_centered_update",
           "normalise_rows", "radio_likelihood", "radio_update"]


def normalise_rows(w: NDArray[np.float64]) -> NDArray[np.float64]:
    """Scale each row so that its largest weight is 1 (rows of zeros stay zero)."""
    m = w.max(axis=1, keepdims=True)
    return np.where(m > 0, w / np.where(m > 0, m, 1.0), 0.0)


def mass_centered_update(st: ParticleState, params: FilterParams,
                         attitude: NDArray[np.integer]) -> None:
    """001 eq. 12 on every user row; azimuth and polar count only where the step is UFH."""
    ufh = (np.asarray(attitude).reshape(-1) == int(AttitudeCode.UFH))[:, None]
    coef = None
    terms, stds = st.terms, st.std
    for f in FEATURES:
        if f.name not in terms:
            continue
        if f.ufh_only and not ufh.any():
            continue
        fp = getattr(params, f.name)
        err = window_mean(terms[f.name])
        thr = fp.threshold
        if fp.std_scale > 0 and f.name in stds:
            s = stds[f.name]
            thr = np.maximum(fp.threshold, fp.std_scale * np.where(np.isfinite(s), s, 0.0))
        c = mass_centered_coefficient(err, fp.award, thr)
        if f.ufh_only:
            c = np.where(ufh, c, 1.0)
        coef = c if coef is None else coef * c
    if coef is not None:
        st.w = st.w * coef


def gaussian_update(st: ParticleState, params: FilterParams) -> None:
    """002-style Gaussian likelihood of the signed strength deltas of the last
    ``gaussian_window`` steps (unknown particles count as the worst of their user)."""
    terms = st.terms.get("strength")
    if terms is None:
        return
    e2 = window_sum(terms)
    alive = st.w > 0
    known = np.isfinite(e2) & alive
    worst = np.max(np.where(known, e2, -np.inf), axis=1, keepdims=True)
    best = np.min(np.where(known, e2, np.inf), axis=1, keepdims=True)
    has = np.isfinite(worst)
    e2 = np.where(np.isfinite(e2), e2, np.where(has, worst, 0.0))
    ll = -(e2 - np.where(has, best, 0.0)) / (2.0 * params.gaussian_sigma ** 2)
    # dead particles (w = 0) may fit better than the best living one: never exp(> 0) * 0
    st.w = st.w * np.exp(np.minimum(ll, 0.0))


def dtw_update(st: ParticleState, fmap: FilterMap, params: FilterParams,
               raw_strength_ut: NDArray[np.float64] | None, max_samples: int = 200) -> None:
    """Magicol-style update of user row 0 from the raw magnetometer strengths of the step.

    The map strength is sampled at ``m`` points along each particle's straight move (``m`` =
    the number of raw samples, at most ``max_samples``); both sequences have their mean
    removed (a per-walk offset cancels) and are compared by DTW.
    """
    if raw_strength_ut is None:
        return
    obs = np.asarray(raw_strength_ut, dtype=np.float64)
    obs = obs[np.isfinite(obs)]
    if len(obs) < 3:
        return
    if len(obs) > max_samples:
        obs = np.interp(np.linspace(0, len(obs) - 1, max_samples), np.arange(len(obs)), obs)
    m = len(obs)
    u = st.shape[0]
    frac = np.linspace(0.0, 1.0, m)
    for r in range(u):
        px = st.prev_x[r][:, None] + frac[None, :] * (st.x[r] - st.prev_x[r])[:, None]
        py = st.prev_y[r][:, None] + frac[None, :] * (st.y[r] - st.prev_y[r])[:, None]
        ref = fmap.sample_many(["strength"], px, py)["strength"]  # (n, m)
        known = np.isfinite(ref)
        cnt = known.sum(axis=1)
        mean = np.where(cnt > 0, np.where(known, ref, 0.0).sum(axis=1) / np.maximum(cnt, 1), 0)
        ref = np.where(known, ref, mean[:, None]) - mean[:, None]
        d = dtw_distance(obs - obs.mean(), ref)
        ll = -d / (m * params.dtw_sigma)
        ll = np.where(cnt > 0, ll, np.nan)
        alive = st.w[r] > 0
        if not np.isfinite(ll[alive]).any():
            continue
        worst = np.nanmin(ll[alive])
        ll = np.where(np.isfinite(ll), ll, worst)
        st.w[r] = st.w[r] * np.exp(np.minimum(ll - np.nanmax(ll[alive]), 0.0))


def magnetic_update(st: ParticleState, fmap: FilterMap, params: FilterParams,
                    attitude: NDArray[np.integer],
                    raw_strength_ut: NDArray[np.float64] | None = None) -> None:
    """Dispatch on ``params.weight_mode``."""
    mode = params.weight_mode
    if mode == "mass_centered":
        mass_centered_update(st, params, attitude)
    elif mode == "gaussian":
        gaussian_update(st, params)
    elif mode == "dtw":
        dtw_update(st, fmap, params, raw_strength_ut)


def radio_likelihood(radio: RadioModel, scan: RadioScan, x_m: NDArray, y_m: NDArray
                     ) -> NDArray[np.float64] | None:
    """``radio.likelihood(scan, x, y)`` when the model has one (None otherwise or when the scan
    tells nothing)."""
    like = getattr(radio, "likelihood", None)
    return None if like is None else like(scan, x_m, y_m)


def radio_update(st: ParticleState, row: int, radio: RadioModel, scan: RadioScan,
                 params: FilterParams,
                 likelihood: NDArray[np.float64] | None = None) -> bool:
    """Multiply row ``row``'s weights by the radio likelihood of ``scan``; True if applied.

    Uses ``radio.likelihood(scan, x, y)`` when the model has it, else a Gaussian around
    ``radio.locate(scan)`` with ``sigma = max(fix sigma, radio_sigma_floor_m)``. A uniform
    share ``radio_outlier`` keeps particles alive when the fix is wrong. ``likelihood``: the
    model's likelihood at the particles, when already computed.
    """
    eps = params.radio_outlier
    x, y = st.x[row], st.y[row]
    lk = likelihood if likelihood is not None else radio_likelihood(radio, scan, x, y)
    if lk is not None:
        lk = np.asarray(lk, dtype=np.float64)
        top = lk.max(initial=0.0)
        if not np.isfinite(top) or top <= 0:
            return False
        g = lk / top
    else:
        fix = radio.locate(scan)
        if fix is None:
            return False
        fx, fy, sig = fix
        position_update(st, row, fx, fy, max(float(sig), params.radio_sigma_floor_m), eps)
        return True
    st.w[row] = st.w[row] * ((1.0 - eps) * g + eps)
    return True


def position_update(st: ParticleState, row: int | NDArray[np.intp], x_m: float | NDArray,
                    y_m: float | NDArray, sigma_m: float | NDArray, outlier: float) -> None:
    """Multiply row ``row``'s weights by a Gaussian of SD ``sigma_m`` (m) around the position
    ``(x_m, y_m)`` (m), mixed with a uniform share ``outlier`` (a wrong position does not kill
    the particles). Several rows at once: ``row`` of shape (k,) and the others (k, 1)."""
    x, y = st.x[row], st.y[row]
    g = np.exp(-((x - x_m) ** 2 + (y - y_m) ** 2) / (2.0 * sigma_m * sigma_m))
    st.w[row] = st.w[row] * ((1.0 - outlier) * g + outlier)
