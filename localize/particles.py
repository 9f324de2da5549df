"""Particle state and the filter's per-step operations, vectorized over users and particles.

Every per-particle array has shape ``(u, n)``: one row per user (the single-user
:class:`~localize.filter.Localizer` uses ``u = 1``; :mod:`localize.engine` stacks many users).
One step of the filter (paper 001, Algorithm 1) is

1. :func:`move` -- genomes drift, step length from eq. 13 with the turn correction of eq. 14,
   heading = compass - heading offset of the map at the particle + noise (eq. 15); a particle
   whose straight move leaves the reachable area dies (weight 0);
2. :func:`observe` -- map values at the new positions enter the per-particle histories;
3. a weight update of :mod:`localize.weights`;
4. :func:`resample` (systematic) and :func:`estimate`.

Headings are azimuths (clockwise from map north): a move of length ``L`` along azimuth ``h`` is
``dx = L sin h, dy = L cos h``. Angles are radians inside, degrees at the edges.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

from localize.errors import LocalizationError
from localize.maps import FilterMap
from localize.params import MAX_STEP_M, FilterParams
from localize.resample import systematic_resample_rows
from localize.weights import newest_delta, term_gaussian, term_mass_centered

__all__ = ["FEATURES", "Feature", "ParticleState", "estimate", "feature_layout", "init_state",
           "inject", "move", "needed_layers", "observe", "reinit_rows", "resample",
           "scatter_init"]


@dataclass(frozen=True)
class Feature:
    """A field feature compared between steps and map."""

    name: str        # key of FilterParams and of the observation
    layer: str       # bundle layer
    angle: bool      # wraps at 360 deg
    ufh_only: bool   # counts only on UFH steps (001 eq. 12)


FEATURES: tuple[Feature, ...] = (
    Feature("strength", "strength", False, False),
    Feature("azimuth", "azimuth", True, True),
    Feature("polar", "polar", False, True),
    Feature("deviation", "heading_offset", True, False),
)


class ParticleState:
    """Particles of ``u`` users with ``n`` particles each, packed in one array.

    Every per-particle quantity is a row of ``data`` (shape ``(F, u, n)``), so that resampling
    is one gather. Views by name:

    Attributes
    ----------
    x, y : ndarray (u, n)
        Position (m).
    a, b : ndarray (u, n)
        Step-length genomes (eq. 13): ``L = a f + b``.
    bias : ndarray (u, n)
        Heading-bias genome (rad).
    flip : ndarray (u, n)
        Which way along the walking axis the particle goes on steps whose compass is an axis
        (:attr:`~localize.steps.AttitudeCode.CARRIED`): 0 along the compass, 1 against it.
        Half the particles start with each, and resampling keeps the way that fits.
    w : ndarray (u, n)
        Weights (not normalised).
    off_s, off_c : ndarray (u, n)
        Map heading offset at the current position as a unit vector (sin, cos); the map's
        mean where unknown.
    prev_x, prev_y : ndarray (u, n)
        Positions before the last move.
    vals : dict name -> ndarray (span + smooth, u, n)
        Map values of a feature at the last positions, oldest first (NaN = unknown).
    terms : dict name -> ndarray (window, u, n)
        Per-step error terms of the feature (:mod:`localize.weights`), oldest first.
    std : dict name -> ndarray (u, n)
        Map uncertainty at the current position (features that use it).
    obs : dict name -> ndarray (span + smooth, u)
        Observed values of the last steps (per user).
    lineage : ndarray (u, n)
        Optional (``with_lineage``): the slot each particle descends from at the last time
        the lineage was reset (-1 = drawn fresh since: injected or re-drawn), for smoothing
        by genealogy (:mod:`localize.smoothing`).
    """

    _BASE = ("x", "y", "a", "b", "bias", "w", "off_s", "off_c", "flip")
    _PREV = ("prev_x", "prev_y")

    def __init__(self, u: int, n: int, layout: dict[str, tuple[int, int]], std_names=(),
                 dtype=np.float64, with_prev: bool = False, with_lineage: bool = False
                 ) -> None:
        nb = len(self._BASE) + (2 if with_prev else 0) + (1 if with_lineage else 0)
        rows = nb + sum(v + t for v, t in layout.values()) + len(std_names)
        self.data = np.zeros((rows, u, n), dtype=dtype)
        self.has_prev = with_prev
        self.has_lineage = with_lineage
        self._nbase = nb
        self._vals: dict[str, slice] = {}
        self._terms: dict[str, slice] = {}
        k = nb
        for name, (nv, nt) in layout.items():
            self._vals[name] = slice(k, k + nv)
            self._terms[name] = slice(k + nv, k + nv + nt)
            k += nv + nt
        self._std_rows: dict[str, int] = {}
        for name in std_names:
            self._std_rows[name] = k
            k += 1
        self.data[nb:] = np.nan
        self.obs = {name: np.full((nv, u), np.nan) for name, (nv, _) in layout.items()}

    @property
    def shape(self) -> tuple[int, int]:
        return self.data.shape[1:]

    @property
    def vals(self) -> dict[str, NDArray]:
        return {k: self.data[s] for k, s in self._vals.items()}

    @property
    def terms(self) -> dict[str, NDArray]:
        return {k: self.data[s] for k, s in self._terms.items()}

    @property
    def std(self) -> dict[str, NDArray]:
        return {k: self.data[r] for k, r in self._std_rows.items()}

    @property
    def lineage(self) -> NDArray:
        if not self.has_lineage:
            raise AttributeError("lineage: this state keeps no lineage")
        return self.data[self._nbase - 1]

    def reset_lineage(self) -> None:
        """Every particle becomes its own ancestor (slot index)."""
        if self.has_lineage:
            self.lineage[...] = np.arange(self.shape[1])

    def cut_lineage(self, rows: int | np.integer | NDArray[np.integer],
                    idx: slice | Sequence[int] | NDArray[np.integer] = slice(None)) -> None:
        """Particles ``idx`` of user ``rows`` were drawn fresh: no ancestor."""
        if self.has_lineage:
            self.data[self._nbase - 1, rows, idx] = -1

    @property
    def nbytes(self) -> int:
        return int(self.data.nbytes + sum(v.nbytes for v in self.obs.values()))

    def feature_rows(self) -> slice:
        """Rows of the feature histories (values and terms) and stds."""
        return slice(self._nbase, self.data.shape[0])

    def gather(self, flat_index: NDArray[np.intp], rows: NDArray[np.intp] | None = None) -> None:
        """Replace particles by those at ``flat_index`` (indexes into the flattened (u, n)
        plane); for all users, or only user ``rows`` (``flat_index`` then has shape
        (len(rows), n))."""
        f, u, n = self.data.shape
        plane = self.data.reshape(f, u * n)
        if rows is None:
            self.data = np.take(plane, flat_index.ravel(), axis=1).reshape(
                (f,) + flat_index.shape)
        else:
            self.data[:, rows] = np.take(plane, flat_index.ravel(), axis=1).reshape(
                f, len(rows), n)

    def subset(self, rows: NDArray[np.intp]) -> ParticleState:
        """A copy holding only some users (same layout)."""
        sub = ParticleState.__new__(ParticleState)
        sub.data = self.data[:, rows]
        sub.has_prev, sub.has_lineage, sub._nbase = self.has_prev, self.has_lineage, self._nbase
        sub._vals, sub._terms, sub._std_rows = self._vals, self._terms, self._std_rows
        sub.obs = {k: v[:, rows] for k, v in self.obs.items()}
        return sub

    def put(self, rows: NDArray[np.intp], sub: ParticleState) -> None:
        """Write a :meth:`subset` back."""
        self.data[:, rows] = sub.data
        for k in self.obs:
            self.obs[k][:, rows] = sub.obs[k]


def _base_property(i: int, name: str, prev: bool = False):
    def get(self: ParticleState) -> NDArray:
        if prev and not self.has_prev:
            raise AttributeError(f"{name}: this state keeps no previous positions")
        return self.data[i]

    def set_(self: ParticleState, value: ArrayLike) -> None:
        if prev and not self.has_prev:
            raise AttributeError(f"{name}: this state keeps no previous positions")
        self.data[i] = value

    return property(get, set_, doc=f"{name} (a view into data)")


for _i, _name in enumerate(ParticleState._BASE + ParticleState._PREV):
    setattr(ParticleState, _name, _base_property(_i, _name, _name in ParticleState._PREV))


def feature_layout(params: FilterParams) -> dict[str, tuple[int, int]]:
    """Per feature: (value rows, term rows) for the weight mode of ``params``."""
    out = {}
    for f in FEATURES:
        fp = getattr(params, f.name)
        if params.weight_mode == "mass_centered" and fp.enabled:
            out[f.name] = (fp.span + fp.smooth - 1, fp.window)
        elif params.weight_mode == "gaussian" and f.name == "strength":
            out[f.name] = (1, params.gaussian_window)
    return out


def needed_layers(params: FilterParams) -> tuple[list[str], list[str]]:
    """Bundle layers (and std layers) the filter looks up with these parameters."""
    layers = ["heading_offset"] if params.use_heading_offset else []
    stds = []
    lay = feature_layout(params)
    for f in FEATURES:
        if f.name in lay:
            layers.append(f.layer)
            if params.weight_mode == "mass_centered" and getattr(params, f.name).std_scale > 0:
                stds.append(f.layer)
    if params.weight_mode == "dtw":
        layers.append("strength")
    return list(dict.fromkeys(layers)), list(dict.fromkeys(stds))


def scatter_init(fmap: FilterMap, rng: np.random.Generator, n: int, cx: float, cy: float,
                 half_width_m: float, max_half_width_m: float = 200.0
                 ) -> tuple[NDArray, NDArray, float]:
    """Positions of ``n`` particles uniform on the reachable part of a square around (cx, cy).

    The square doubles until it holds reachable cells (up to ``max_half_width_m``).

    Returns
    -------
    (x (n,), y (n,), half-width used (m))

    Raises
    ------
    LocalizationError
        No reachable cell within ``max_half_width_m`` of the centre, or a non-finite centre.
    """
    if not (np.isfinite(cx) and np.isfinite(cy)):
        raise LocalizationError(f"start position ({cx}, {cy}) is not finite")
    hw = float(half_width_m)
    if not (np.isfinite(hw) and hw > 0):  # the doubling below would never end
        raise LocalizationError(f"start half-width {half_width_m} m is not positive and finite")
    while True:
        pts = fmap.random_reachable(rng, n, cx, cy, hw)
        if pts is not None:
            return pts[0], pts[1], hw
        if hw >= max_half_width_m:
            raise LocalizationError(f"no reachable map cell within {max_half_width_m:.0f} m of "
                                    f"the start position ({cx:.1f}, {cy:.1f}) m: wrong floor or "
                                    "bundle?")
        hw = min(2.0 * hw, max_half_width_m)


def init_state(fmap: FilterMap, params: FilterParams, rng: np.random.Generator,
               centers_xy: NDArray, half_widths_m: NDArray, dtype: DTypeLike = np.float64,
               n: int | None = None, with_lineage: bool = False) -> ParticleState:
    """Particles of ``u`` users around their start positions, equal weights.

    Parameters
    ----------
    centers_xy : ndarray (u, 2)
        Start positions (m).
    half_widths_m : ndarray (u,)
        ``delta`` per user (m).
    n : int, optional
        Particles per user (default ``params.n_particles``).
    with_lineage : bool
        Keep each particle's ancestor slot (see :class:`ParticleState`).
    """
    centers_xy = np.asarray(centers_xy, dtype=np.float64).reshape(-1, 2)
    u, n = len(centers_xy), int(params.n_particles if n is None else n)
    x = np.empty((u, n))
    y = np.empty((u, n))
    for k in range(u):  # one draw per user (users start at different places)
        x[k], y[k], _ = scatter_init(fmap, rng, n, centers_xy[k, 0], centers_xy[k, 1],
                                     float(np.broadcast_to(half_widths_m, (u,))[k]))
    _, stds = needed_layers(params)
    st = ParticleState(u, n, feature_layout(params),
                       [f.name for f in FEATURES if f.layer in stds], dtype=dtype,
                       with_prev=params.weight_mode == "dtw", with_lineage=with_lineage)
    st.reset_lineage()
    a = rng.normal(params.genome_a_mean, params.genome_a_sd, (u, n))
    b = (params.step_length_nominal_m - a * params.step_feature_nominal
         + rng.normal(0.0, params.genome_b_sd, (u, n)))
    st.x, st.y = x, y
    if st.has_prev:
        st.prev_x, st.prev_y = x, y
    st.a = np.clip(a, *params.genome_a_range)
    st.b = np.clip(b, *params.genome_b_range)
    clamp_genomes(st, params)
    if params.heading_bias_sd_deg > 0:
        st.bias = rng.normal(0.0, np.radians(params.heading_bias_sd_deg), (u, n))
    st.flip = np.arange(n) % 2
    st.w = 1.0
    observe(st, fmap, params, None, shift=False)
    return st


def clamp_genomes(st: ParticleState, p: FilterParams) -> None:
    """Keep each genome's step length at the nominal frequency within
    ``p.step_length_range_m`` (by moving ``b``)."""
    a, b = st.a, st.b
    nominal = a * p.step_feature_nominal + b
    lo, hi = p.step_length_range_m
    b += np.clip(nominal, lo, hi) - nominal


def move(st: ParticleState, fmap: FilterMap, params: FilterParams, rng: np.random.Generator,
         compass_deg: NDArray, freq_hz: NDArray, turn_deg: NDArray,
         delta_acc_ms2: NDArray | None = None, compass_axis: NDArray | None = None
         ) -> NDArray[np.bool_]:
    """Move every particle by one step (001 eqs. 13-15); returns which stayed reachable.

    Parameters
    ----------
    compass_deg, freq_hz, turn_deg : ndarray (u,)
        Per user: compass heading (deg), step frequency (Hz, NaN = nominal), heading change
        over the step (deg).
    delta_acc_ms2 : ndarray (u,), optional
        Acceleration swing of the step (m/s^2), the input of the Weinberg model (NaN or None
        = nominal).
    compass_axis : ndarray of bool (u,), optional
        Users whose compass is the walking axis this step: each particle goes the way its
        ``flip`` says.

    Returns
    -------
    ndarray of bool (u, n)
        False for particles whose move left the reachable area (their weight is set to 0).
    """
    u, n = st.shape
    p = params
    f32 = np.float32
    z = rng.standard_normal((5, u, n), dtype=f32)
    if p.genome_drift_a > 0:
        a = st.a
        a += f32(p.genome_drift_a) * z[0]
        np.clip(a, *p.genome_a_range, out=a)
    if p.genome_drift_b > 0:
        b = st.b
        b += f32(p.genome_drift_b) * z[1]
        np.clip(b, *p.genome_b_range, out=b)
    if p.genome_drift_a > 0 or p.genome_drift_b > 0:
        clamp_genomes(st, p)
    if p.heading_bias_drift_deg > 0:
        bias = st.bias
        bias += f32(np.radians(p.heading_bias_drift_deg)) * z[2]
    if p.step_model == "weinberg":
        fr = np.full((u, 1), np.nan) if delta_acc_ms2 is None else np.maximum(
            np.asarray(delta_acc_ms2, dtype=np.float64).reshape(u, 1), 0.0) ** 0.25
    else:
        fr = np.asarray(freq_hz, dtype=np.float64).reshape(u, 1)
    fr = np.where(np.isfinite(fr), fr, p.step_feature_nominal).astype(f32)
    length = st.a * fr + st.b + f32(p.step_length_noise_m) * z[3]
    np.clip(length, 0.0, MAX_STEP_M, out=length)
    if p.turn_correction:
        th = np.minimum(np.abs(np.radians(np.asarray(turn_deg, dtype=np.float64))), np.pi)
        th = np.where(np.isfinite(th), th, 0.0).reshape(u, 1)
        length *= np.sin((np.pi - th) / 2.0).astype(f32)
    # Walking azimuth h = compass - offset(x, y) - (bias + noise) (eq. 15), composed from unit
    # vectors: the offset comes interpolated as (sin, cos), the small error angle in float32.
    e = (st.bias + f32(np.radians(p.heading_noise_deg)) * z[4]).astype(f32, copy=False)
    se, ce = np.sin(e), np.cos(e)
    c_rad = np.radians(np.asarray(compass_deg, dtype=np.float64)).reshape(u, 1)
    if compass_axis is not None and np.any(compass_axis):
        c_rad = c_rad + np.pi * (st.flip * np.asarray(compass_axis, bool).reshape(u, 1))
    sc, cc = np.sin(c_rad).astype(f32), np.cos(c_rad).astype(f32)
    if p.use_heading_offset:
        os_, oc = st.off_s, st.off_c
        s1 = sc * oc - cc * os_
        c1 = cc * oc + sc * os_
    else:
        s1, c1 = sc, cc
    sh = s1 * ce - c1 * se
    ch = c1 * ce + s1 * se
    x, y = st.x, st.y
    if st.has_prev:
        st.prev_x, st.prev_y = x, y
    nx = x + length * sh
    ny = y + length * ch
    ok = fmap.segment_free(x, y, nx, ny, max_len_m=float(length.max(initial=0.0)))
    st.x, st.y = nx, ny
    st.w = np.where(ok, st.w, 0.0)
    return ok


def _layer_values(vals: dict, layer: str) -> NDArray | None:
    """A looked-up layer as values (angle layers looked up as (sin, cos) become degrees)."""
    v = vals.get(layer)
    if isinstance(v, tuple):
        return np.degrees(np.arctan2(v[0], v[1]))
    return v


def _lookup_keys(fmap: FilterMap, params: FilterParams) -> list[str]:
    layers, stds = needed_layers(params)
    return [k for k in layers if fmap.has(k)] + [f"{k}_std" for k in stds
                                                 if fmap.has(f"{k}_std")]


def _set_offset(st: ParticleState, fmap: FilterMap, vals: dict, rows=slice(None)) -> None:
    vec = vals.get("heading_offset")
    m = np.radians(fmap.mean_heading_offset_deg)
    if vec is None:
        st.off_s[rows], st.off_c[rows] = np.sin(m), np.cos(m)
    else:
        s, c = vec
        good = np.isfinite(s)
        st.off_s[rows] = np.where(good, s, np.sin(m))
        st.off_c[rows] = np.where(good, c, np.cos(m))


def observe(st: ParticleState, fmap: FilterMap, params: FilterParams,
            obs: dict[str, NDArray] | None, *, shift: bool = True) -> None:
    """Look up the map at the particles' positions, push map and observed values into the
    histories and compute each feature's newest error term.

    Parameters
    ----------
    obs : dict name -> ndarray (u,), optional
        Observed feature values of this step per user (NaN = not measured).
    shift : bool
        A new step (False at initialisation: the start positions only fill the newest value).
    """
    keys = _lookup_keys(fmap, params)
    if not keys:
        return
    u, n = st.shape
    vals = fmap.sample_many(keys, st.x, st.y, vectors=("heading_offset",))
    if params.use_heading_offset:
        _set_offset(st, fmap, vals)
    gaussian = params.weight_mode == "gaussian"
    all_vals, all_terms, stds_now = st.vals, st.terms, st.std
    for f in FEATURES:
        if f.name not in all_vals:
            continue
        past = all_vals[f.name]
        new = _layer_values(vals, f.layer)
        if new is None:
            new = np.full((u, n), np.nan)
        if f.name in stds_now and f"{f.layer}_std" in vals:
            stds_now[f.name][...] = vals[f"{f.layer}_std"]
        if shift:
            o = st.obs[f.name]
            o_new = np.full(u, np.nan) if obs is None else np.asarray(
                obs.get(f.name, np.nan), dtype=np.float64).reshape(u)
            fp = getattr(params, f.name)
            span, smooth = (1, 1) if gaussian else (fp.span, fp.smooth)
            if len(past) == 1:
                d_map = new - past[0]
                d_obs = o_new - o[0]
                if f.angle:
                    d_map = (d_map + 180.0) % 360.0 - 180.0
                    d_obs = (d_obs + 180.0) % 360.0 - 180.0
            else:
                d_map = newest_delta(np.concatenate([past, new[None]]), span, smooth, f.angle)
                d_obs = newest_delta(np.concatenate([o, o_new[None]]), span, smooth, f.angle)
            term = term_gaussian(d_map, d_obs) if gaussian else term_mass_centered(d_map,
                                                                                  d_obs)
            t = all_terms[f.name]
            t[:-1] = t[1:]
            t[-1] = term
            o[:-1] = o[1:]
            o[-1] = o_new
            past[:-1] = past[1:]
        past[-1] = new


def resample(st: ParticleState, rng: np.random.Generator,
             rows: NDArray[np.bool_] | None = None, n_out: int | None = None) -> None:
    """Systematic resampling of every user row (or only ``rows``); weights reset to 1.

    Genomes, histories and offsets follow their particles (001: genomes evolve through
    resampling): one gather of the packed particle array. ``n_out`` changes the number of
    particles (all rows only).
    """
    u, n = st.shape
    if rows is None:
        idx = systematic_resample_rows(st.w, rng, n_out)
        st.gather(idx + (np.arange(u) * n)[:, None])
        st.w = 1.0
        return
    r = np.flatnonzero(rows)
    if len(r) == 0:
        return
    idx = systematic_resample_rows(st.w[r], rng)
    st.gather(idx + (r * n)[:, None], rows=r)
    st.data[ParticleState._BASE.index("w"), r] = 1.0


def estimate(st: ParticleState, uniform: bool = False) -> tuple[NDArray, NDArray, NDArray]:
    """Weighted mean position and spread per user.

    ``uniform=True`` skips the weights (right after resampling, when they are all equal).

    Returns
    -------
    (x (u,), y (u,), spread (u,)) in metres; spread = sqrt of the summed x and y variances.
    """
    x, y = st.x, st.y
    if uniform:
        mx, my = x.mean(axis=1), y.mean(axis=1)
        dx, dy = x - mx[:, None], y - my[:, None]
        var = (dx * dx + dy * dy).mean(axis=1)
        return mx, my, np.sqrt(var)
    w = st.w
    tot = w.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mx = (w * x).sum(axis=1) / tot
        my = (w * y).sum(axis=1) / tot
        dx, dy = x - mx[:, None], y - my[:, None]
        var = (w * (dx * dx + dy * dy)).sum(axis=1) / tot
    return mx, my, np.sqrt(np.maximum(var, 0.0))


def reinit_rows(st: ParticleState, fmap: FilterMap, params: FilterParams,
                rng: np.random.Generator, rows: NDArray[np.intp], centers_xy: NDArray,
                half_widths_m: NDArray) -> NDArray[np.float64]:
    """Re-draw the particles of some users around new centres (recovery after all died).

    Genomes are kept (they carry the learned step length); positions, weights, the map
    histories and the way along a carried phone's axis (``flip``, half each way) of those rows
    are reset. Returns the half-widths actually used (m).
    """
    rows = np.asarray(rows, dtype=np.intp)
    n = st.shape[1]
    used = np.empty(len(rows))
    for k, r in enumerate(rows):
        x, y, used[k] = scatter_init(fmap, rng, n, float(centers_xy[k][0]),
                                     float(centers_xy[k][1]), float(half_widths_m[k]))
        st.x[r], st.y[r] = x, y
        if st.has_prev:
            st.prev_x[r], st.prev_y[r] = x, y
        st.w[r] = 1.0
        st.flip[r] = np.arange(n) % 2
        st.data[st.feature_rows(), r] = np.nan
        st.cut_lineage(r)
    keys = _lookup_keys(fmap, params)
    if keys and len(rows):
        vals = fmap.sample_many(keys, st.x[rows], st.y[rows], vectors=("heading_offset",))
        if params.use_heading_offset:
            _set_offset(st, fmap, vals, rows)
        all_vals, stds_now = st.vals, st.std
        for f in FEATURES:
            if f.name in all_vals and f.layer in vals:
                all_vals[f.name][-1, rows] = _layer_values(vals, f.layer)
            if f.name in stds_now and f"{f.layer}_std" in vals:
                stds_now[f.name][rows] = vals[f"{f.layer}_std"]
    return used


def inject(st: ParticleState, fmap: FilterMap, params: FilterParams, rng: np.random.Generator,
           row: int, fraction: float, center_xy: Sequence[float] | NDArray,
           half_width_m: float) -> int:
    """Replace a random share of one user's particles by fresh ones around a fix.

    Guards against a filter locked onto a wrong corridor (a wrong start, or a lost track): the
    newcomers sit uniformly on the reachable cells of the square around the fix, inherit the
    genomes of random particles (the learned step length), start with empty error histories
    (they are judged from their next step on), the mean weight of the user, and half each way
    along a carried phone's axis (``flip``). Returns how many particles were replaced.
    """
    n = st.shape[1]
    k = round(fraction * n)
    if k <= 0:
        return 0
    pts = fmap.random_reachable(rng, k, float(center_xy[0]), float(center_xy[1]),
                                float(half_width_m))
    if pts is None:
        return 0
    idx = rng.choice(n, k, replace=False)
    w_mean = float(st.w[row].mean())
    st.data[st.feature_rows(), row, idx] = np.nan
    st.x[row, idx], st.y[row, idx] = pts
    if st.has_prev:
        st.prev_x[row, idx], st.prev_y[row, idx] = pts
    st.w[row, idx] = w_mean
    st.flip[row, idx] = np.arange(k) % 2
    st.cut_lineage(row, idx)
    keys = _lookup_keys(fmap, params)
    if keys:
        vals = fmap.sample_many(keys, pts[0], pts[1], vectors=("heading_offset",))
        if params.use_heading_offset:
            vec = vals.get("heading_offset")
            m = np.radians(fmap.mean_heading_offset_deg)
            s, c = (np.sin(m), np.cos(m)) if vec is None else vec
            good = np.isfinite(s)
            st.off_s[row, idx] = np.where(good, s, np.sin(m))
            st.off_c[row, idx] = np.where(good, c, np.cos(m))
        all_vals, stds_now = st.vals, st.std
        for f in FEATURES:
            if f.name in all_vals and f.layer in vals:
                all_vals[f.name][-1, row, idx] = _layer_values(vals, f.layer)
            if f.name in stds_now and f"{f.layer}_std" in vals:
                stds_now[f.name][row, idx] = vals[f"{f.layer}_std"]
    return k


def start_half_width_m(params: FilterParams, fix_sigma_m: ArrayLike) -> NDArray:
    """Half-widths (m) of the start squares of filters started at positions whose radio fix
    accuracy is ``fix_sigma_m`` (m, any shape; NaN: a known position, not a fix):
    ``init_half_width_m``, widened to ``init_from_fix_scale * fix_sigma_m`` for a fix."""
    sigma = np.asarray(fix_sigma_m, dtype=np.float64)
    return np.where(np.isfinite(sigma),
                    np.fmax(params.init_half_width_m, params.init_from_fix_scale * sigma),
                    params.init_half_width_m)


def inject_around_fix(st: ParticleState, fmap: FilterMap, params: FilterParams,
                      rng: np.random.Generator, row: int, fraction: float,
                      fix_xy: Sequence[float], sigma_m: float) -> int:
    """:func:`inject` around a radio fix of accuracy ``sigma_m`` (m): the square's half-width
    is ``max(radio_sigma_floor_m, init_from_fix_scale * sigma_m)``."""
    return inject(st, fmap, params, rng, row, fraction, fix_xy,
                  max(params.radio_sigma_floor_m, params.init_from_fix_scale * float(sigma_m)))


def inject_around_guide(st: ParticleState, fmap: FilterMap, params: FilterParams,
                        rng: np.random.Generator, row: int, guide_xy: Sequence[float],
                        sigma_m: float) -> int:
    """:func:`inject` of ``radio_inject_fraction`` of the particles around the walk
    alignment's position (``radio_guide="align"``) of SD ``sigma_m`` (m): the square's
    half-width is ``init_from_fix_scale * sigma_m``."""
    return inject(st, fmap, params, rng, row, params.radio_inject_fraction, guide_xy,
                  params.init_from_fix_scale * float(sigma_m))


def estimate_mode(st: ParticleState, cell_m: float = 1.0, size: int = 64
                  ) -> tuple[NDArray, NDArray]:
    """Position of the densest part of each user's particle cloud.

    Particles are binned into ``cell_m`` cells on a ``size x size`` grid anchored at the
    cloud's minimum corner (particles beyond it fall into the last cells); the block of 3 x 3
    cells with the most weight wins, and the estimate is the weighted mean of its particles.
    Unlike the mean, it stays on one hypothesis when the cloud is multimodal (two corridors).

    Returns
    -------
    (x (u,), y (u,)) in metres
    """
    u = st.shape[0]
    x, y, w = st.x, st.y, st.w
    x0 = x.min(axis=1, keepdims=True)
    y0 = y.min(axis=1, keepdims=True)
    ix = np.minimum(((x - x0) / cell_m).astype(np.intp), size - 1)
    iy = np.minimum(((y - y0) / cell_m).astype(np.intp), size - 1)
    flat = (np.arange(u)[:, None] * size + iy) * size + ix
    hist = np.bincount(flat.ravel(), weights=w.ravel(), minlength=u * size * size).reshape(
        u, size, size)
    pad = np.zeros((u, size + 2, size + 2))
    pad[:, 1:-1, 1:-1] = hist
    box = sum(pad[:, 1 + di:1 + di + size, 1 + dj:1 + dj + size]
              for di in (-1, 0, 1) for dj in (-1, 0, 1))
    best = np.argmax(box.reshape(u, -1), axis=1)
    by, bx = np.divmod(best, size)
    sel = (np.abs(ix - bx[:, None]) <= 1) & (np.abs(iy - by[:, None]) <= 1)
    ws = np.where(sel, w, 0.0)
    tot = ws.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (ws * x).sum(axis=1) / tot, (ws * y).sum(axis=1) / tot
