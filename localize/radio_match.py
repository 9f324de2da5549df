"""Fingerprint matching kernels (numpy only, shared by the mapping stage and the localizer).

Scans and reference points are dense matrices over one list of transmitters, RSSI in dBm with
NaN = not heard. Matching works on the *powed* representation (Torres-Sospedra et al.)::

    p = ((rssi - floor) / -floor) ** beta,   0 where not heard or below the floor,

which keeps "not heard" at 0 without baking a fake RSSI into storage and lets strong
transmitters dominate. The Sorensen (Bray-Curtis) distance between two such vectors,
``sum |a - b| / sum (a + b)``, lies in [0, 1]. The Gaussian log-likelihood of eqs. 1-2 / 9-10 of
the papers is here too, for the probabilistic matcher and the online RSSI calibration.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from localize.errors import LocalizationError

__all__ = ["AGE_DECAY_MS", "AGE_FRESH_MS", "BLE_MIN_STRONGEST_DBM", "ReferenceMotion",
           "ReferenceNeighbours", "WalkSmoothing", "age_weights", "euclidean_distances",
           "gaussian_loglik", "knn_positions", "min_strongest_dbm", "powed",
           "reference_neighbours", "scan_matrices", "scan_rssi_matrix", "smoothed_distances",
           "sorensen_distances", "too_weak", "walk_scores"]

FloatArray = NDArray[np.float64]


def scan_rssi_matrix(scans: Sequence[Any], index: dict[str, int]) -> FloatArray:
    """RSSI of scans (objects with ``keys`` and ``rssi_dbm``, e.g. ``RadioScan``; None allowed)
    as a matrix over the transmitters of ``index`` (key -> column), shape (S, len(index))
    (dBm; NaN = not heard, unknown keys ignored)."""
    return scan_matrices(scans, index)[0]


def scan_matrices(scans: Sequence[Any], index: dict[str, int]
                  ) -> tuple[FloatArray, FloatArray]:
    """RSSI (dBm) and row ages (ms) of scans, both laid out as :func:`scan_rssi_matrix`; an age
    is NaN where not heard or where the scan carries no ``age_ms``."""
    rssi = np.full((len(scans), len(index)), np.nan)
    age = np.full_like(rssi, np.nan)
    for i, scan in enumerate(scans):
        keys = [] if scan is None else np.asarray(scan.keys).astype(str).tolist()
        if not keys:
            continue
        idx = np.fromiter((index.get(k, -1) for k in keys), dtype=np.int64, count=len(keys))
        known = idx >= 0
        rssi[i, idx[known]] = np.asarray(scan.rssi_dbm, dtype=np.float64)[known]
        ages = getattr(scan, "age_ms", None)
        if ages is not None:
            age[i, idx[known]] = np.asarray(ages, dtype=np.float64)[known]
    return rssi, age


def powed(rssi_dbm: FloatArray, floor_dbm: float = -100.0, beta: float = float(np.e)
          ) -> FloatArray:
    """Powed representation of RSSI (dBm) in [0, 1]; NaN (not heard) and values at or below
    ``floor_dbm`` give 0."""
    r = np.asarray(rssi_dbm, dtype=np.float64)
    out = np.zeros(r.shape)
    heard = r > floor_dbm  # False for NaN
    out[heard] = np.minimum((r[heard] - floor_dbm) / -floor_dbm, 1.0) ** beta
    return out


def too_weak(rssi_dbm: FloatArray, min_strongest_dbm: float) -> NDArray[np.bool_]:
    """Scans (rows of ``rssi_dbm``, dBm, NaN = not heard) whose strongest value is below
    ``min_strongest_dbm``: not located (:data:`BLE_MIN_STRONGEST_DBM`; none when -inf).
    Shape (S,)."""
    r = np.asarray(rssi_dbm, dtype=np.float64)
    if min_strongest_dbm == -np.inf:  # the default: nothing is cut, and no pass over the matrix
        return np.zeros(r.shape[:-1], dtype=bool)
    strongest = np.where(np.isfinite(r), r, -np.inf).max(axis=-1, initial=-np.inf)
    return strongest < min_strongest_dbm


def min_strongest_dbm(kind: str) -> float:
    """The weakest strongest value (dBm) a scan of ``kind`` (``"wifi"``, ``"ble"``) needs to
    be located: :data:`BLE_MIN_STRONGEST_DBM` for BLE (-inf by default), -inf (every scan)
    for Wi-Fi. What the localizer's positioner and the mapping side's default matcher both
    use."""
    if kind not in ("wifi", "ble"):
        raise ValueError(f"kind must be 'wifi' or 'ble', not {kind!r}")
    return BLE_MIN_STRONGEST_DBM if kind == "ble" else float("-inf")


#: A BLE window whose strongest known beacon reads below this (dBm, calibrated) is not
#: located; -inf (the default): every window that hears a known beacon is. Such windows are
#: far off on the real site1 traces (below -88 dBm: 13.6 m median against 6.3 m for the others,
#: held-out 2 s windows), but a limit does not make the localizer better on the walks that keep
#: a fix (-92 to -76 dBm: within 0.2 m of none in median, 5-fold by walk, three phone scales),
#: and it leaves walks without any fix: at -88 dBm 24 of 305 walks on the survey phones (10
#: without a limit), 74 on a phone reading 12 dB low (25), whose users then get no position
#: (``docs/localize.md``, "Walks without Wi-Fi"). Kept as a setting for sites where it helps;
#: ``benchmarks/localize_accuracy.py --ble-min-dbm X`` measures it. Wi-Fi scans are never cut.
BLE_MIN_STRONGEST_DBM = float("-inf")

#: Scan rows up to this age (ms) count in full; older ones decay (:func:`age_weights`).
AGE_FRESH_MS = 2500.0
#: Decay time (ms) of older rows' weight; with :data:`AGE_FRESH_MS` the best of a grid on
#: site1 (10-fold: 3.65 m median against 3.84 m with rows over 3 s dropped and 4.30 m with
#: every row in full).
AGE_DECAY_MS = 4000.0


def age_weights(age_ms: FloatArray, fresh_ms: float, decay_ms: float) -> FloatArray:
    """Weight of a row by its age: 1 up to ``fresh_ms``, then ``exp(-(age - fresh) / decay)``.
    NaN ages (not heard, or unknown) give 1."""
    a = np.nan_to_num(np.asarray(age_ms, dtype=np.float64), nan=0.0)
    return np.exp(-np.clip(a - fresh_ms, 0.0, None) / decay_ms)


def sorensen_distances(q: FloatArray, r: FloatArray) -> FloatArray:
    """Sorensen distance between every row of ``q`` (S, A) and of ``r`` (R, A), both >= 0.

    Only the columns a query hears are visited (``min(a, b) = 0`` elsewhere), so the cost is
    S * R * (transmitters per scan). Two all-zero rows are at distance 1.
    """
    q = np.asarray(q, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    out = np.ones((len(q), len(r)))
    if len(q) == 0 or len(r) == 0:
        return out
    r_sum = r.sum(axis=1)
    r32 = r.astype(np.float32)
    for i, row in enumerate(q):
        nz = np.flatnonzero(row > 0)
        if len(nz) == 0:
            continue
        common = np.minimum(r32[:, nz], row[nz].astype(np.float32)).sum(axis=1, dtype=np.float64)
        denom = row[nz].sum() + r_sum
        out[i] = 1.0 - 2.0 * common / denom
    return out


def euclidean_distances(q: FloatArray, r: FloatArray) -> FloatArray:
    """Euclidean distance between every row of ``q`` (S, A) and of ``r`` (R, A)."""
    q = np.asarray(q, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    d2 = (q ** 2).sum(1)[:, None] + (r ** 2).sum(1)[None, :] - 2.0 * q @ r.T
    return np.sqrt(np.maximum(d2, 0.0))


@dataclass(frozen=True)
class ReferenceNeighbours:
    """Gaussian weights between nearby reference points, row-normalised, in CSR layout: the
    neighbours of reference ``i`` are ``cols[indptr[i]:indptr[i + 1]]`` (itself included) with
    weights ``weights[...]`` summing to 1."""

    indptr: NDArray[np.intp]
    cols: NDArray[np.intp]
    weights: FloatArray


def reference_neighbours(xy_m: FloatArray, sigma_m: float, radius_m: float | None = None,
                         chunk: int = 64) -> ReferenceNeighbours:
    """Neighbours of every reference point within ``radius_m`` (default ``2.5 sigma_m``),
    weighted ``exp(-d^2 / (2 sigma_m^2))`` and normalised per reference point.

    ``xy_m``: shape (R, 2), m. The points are sorted by x and every chunk of ``chunk`` points is
    compared with the points in its x range only (3,000 reference points on a 60 x 50 m floor:
    about 50 ms).
    """
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    radius = 2.5 * sigma_m if radius_m is None else radius_m
    order = np.argsort(xy[:, 0], kind="stable")
    sx = xy[order]
    rows, cols, d2s = [], [], []
    for a in range(0, len(sx), chunk):
        part = sx[a:a + chunk]
        lo = np.searchsorted(sx[:, 0], part[0, 0] - radius, side="left")
        hi = np.searchsorted(sx[:, 0], part[-1, 0] + radius, side="right")
        d2 = ((part[:, None, :] - sx[None, lo:hi, :]) ** 2).sum(axis=2)
        r, c = np.nonzero(d2 <= radius * radius)
        rows.append(order[r + a])
        cols.append(order[c + lo])
        d2s.append(d2[r, c])
    row = np.concatenate(rows) if rows else np.empty(0, np.intp)
    col = np.concatenate(cols) if cols else np.empty(0, np.intp)
    d2 = np.concatenate(d2s) if d2s else np.empty(0)
    by = np.lexsort((col, row))
    row, col = row[by], col[by]
    w = np.exp(-d2[by] / (2.0 * sigma_m * sigma_m))
    indptr = np.concatenate([[0], np.cumsum(np.bincount(row, minlength=len(xy)))])
    if len(w):
        w = w / np.repeat(np.add.reduceat(w, indptr[:-1]), np.diff(indptr))
    return ReferenceNeighbours(indptr.astype(np.intp), col.astype(np.intp), w)


def smoothed_distances(dist: FloatArray, neighbours: ReferenceNeighbours, mix: float
                       ) -> FloatArray:
    """Signal distances (S, R) mixed with their neighbourhood average over reference points:
    ``(1 - mix) * d[:, i] + mix * sum_j w_ij d[:, j]``. A reference point then matches a scan
    well only where its neighbours do too, which damps single noisy reference points."""
    dist = np.asarray(dist, dtype=np.float64)
    if mix <= 0 or dist.size == 0:
        return dist
    nb = neighbours
    out = np.empty_like(dist)
    rows = max(1, (1 << 22) // max(len(nb.cols), 1))  # bounds the (rows, pairs) temporary
    for a in range(0, len(dist), rows):
        d = dist[a:a + rows]
        avg = np.add.reduceat(d[:, nb.cols] * nb.weights, nb.indptr[:-1], axis=1)
        out[a:a + rows] = (1.0 - mix) * d + mix * avg
    return out


@dataclass(frozen=True)
class WalkSmoothing:
    """Whole-walk matching: every scan's match is informed by the walk's other scans.

    A scan's likelihood at reference point ``r`` is ``exp(-(d_r - min d) / tau)`` (``d``: its
    signal distances); between two scans ``dt`` seconds apart the walker moves by a Gaussian
    of ``sigma = max(min_sigma_m, speed_mps * dt)`` metres over the reference points. The
    forward (earlier scans) and, with ``direction="both"``, backward (later scans) messages
    give every scan a prior over the reference points, and its neighbours are picked by
    ``d - tau * log(prior)`` (:func:`walk_scores`). ``"forward"`` uses the past only, as in
    real time. A gap whose ``sigma`` exceeds ``max_sigma_m`` breaks the chain.

    Defaults measured on site1 (grouped 10-fold by walk, ``benchmarks/wifi_accuracy.py``):
    ``tau`` 0.01-0.03 and ``speed_mps`` 1.5-2 give 3.44-3.49 m median against 3.65 m scan by
    scan; the best of a grid chosen on half of the folds scores on the other half what these
    defaults score there (3.49 / 3.41 m against 3.50 / 3.40 m).
    """

    tau: float = 0.02
    speed_mps: float = 2.0
    min_sigma_m: float = 1.0
    max_sigma_m: float = 30.0
    direction: str = "both"

    def __post_init__(self) -> None:
        if self.direction not in ("both", "forward"):
            raise LocalizationError(f"walk smoothing: direction must be 'both' or 'forward', "
                                    f"not {self.direction!r}")
        if not (self.tau > 0 and self.speed_mps > 0 and 0 < self.min_sigma_m
                <= self.max_sigma_m):
            raise LocalizationError(f"walk smoothing needs tau > 0, speed_mps > 0 and "
                                    f"0 < min_sigma_m <= max_sigma_m; got {self}")


SIGMA_LEVELS_M = (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0)
"""Motion spreads (m) with a precomputed transition; a wider spread is several steps of one."""


class ReferenceMotion:
    """Gaussian moves of the walker between reference points (sparse, built per spread on
    first use and kept).

    ``xy_m``: reference positions, shape (R, 2), m.
    """

    def __init__(self, xy_m: FloatArray) -> None:
        self.xy_m = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        self._steps: dict[float, tuple[ReferenceNeighbours, NDArray[np.intp]]] = {}

    def _step(self, sigma_m: float) -> tuple[ReferenceNeighbours, NDArray[np.intp]]:
        if sigma_m not in self._steps:
            nb = reference_neighbours(self.xy_m, sigma_m)
            self._steps[sigma_m] = (nb, np.repeat(np.arange(len(self.xy_m)), np.diff(nb.indptr)))
        return self._steps[sigma_m]

    def plan(self, sigma_m: float) -> list[float]:
        """The spreads of :data:`SIGMA_LEVELS_M` applied in turn for a move of ``sigma_m``
        (their variances add up to about ``sigma_m ** 2``)."""
        top = SIGMA_LEVELS_M[-1]
        n = max(1, int(np.ceil((sigma_m / top) ** 2)))
        each = sigma_m / np.sqrt(n)
        level = SIGMA_LEVELS_M[int(np.argmin([abs(np.log(each / v)) for v in SIGMA_LEVELS_M]))]
        return [level] * n

    def forward(self, p: FloatArray, sigma_m: float) -> FloatArray:
        """Where mass ``p`` (R,) over the reference points goes: ``sum_i p_i T_ij``."""
        for level in self.plan(sigma_m):
            nb, rows = self._step(level)
            p = np.bincount(nb.cols, weights=p[rows] * nb.weights, minlength=len(p))
        return p

    def backward(self, v: FloatArray, sigma_m: float) -> FloatArray:
        """The expectation of ``v`` (R,) one move ahead: ``sum_j T_ij v_j``."""
        for level in self.plan(sigma_m):
            nb, _ = self._step(level)
            v = np.add.reduceat(v[nb.cols] * nb.weights, nb.indptr[:-1])
        return v


def walk_scores(dist: FloatArray, t_ms: FloatArray, motion: ReferenceMotion,
                params: WalkSmoothing = WalkSmoothing()) -> FloatArray:
    """Neighbour-picking scores of one walk's scans: ``d - tau * log(prior)``.

    Parameters
    ----------
    dist : ndarray, shape (S, R)
        Signal distances of the walk's scans to the reference points (lower is closer). A
        scan that shares nothing with any reference point (all distances equal) carries no
        information and passes the messages on.
    t_ms : ndarray, shape (S,)
        Scan times (ms), any order.
    motion : ReferenceMotion
        Of the reference points the distances refer to.

    Returns
    -------
    ndarray, shape (S, R)
        ``dist`` plus ``-tau * log(prior)``, the prior (normalised to a maximum of 1) coming
        from the walk's other scans (:class:`WalkSmoothing`).
    """
    dist = np.asarray(dist, dtype=np.float64)
    n, r = dist.shape
    if n < 2:
        return dist.copy()
    order = np.argsort(np.asarray(t_ms, dtype=np.float64), kind="stable")
    d = dist[order]
    gap_s = np.diff(np.asarray(t_ms, dtype=np.float64)[order]) / 1000.0
    sigma = np.maximum(params.min_sigma_m, params.speed_mps * gap_s)
    like = np.exp(-(d - d.min(axis=1, keepdims=True)) / params.tau)
    prior = np.ones((n, r))
    post = like[0] / like[0].sum()
    for i in range(1, n):
        if sigma[i - 1] <= params.max_sigma_m:
            pred = motion.forward(post, sigma[i - 1])
            prior[i] = pred / pred.max()
        post = prior[i] * like[i]
        total = post.sum()
        post = post / total if total > 0 else like[i] / like[i].sum()
    if params.direction == "both":
        ahead = np.ones(r)
        for i in range(n - 2, -1, -1):
            if sigma[i] <= params.max_sigma_m:
                ahead = motion.backward(ahead * like[i + 1], sigma[i])
                top = ahead.max()
                ahead = ahead / top if top > 0 else np.ones(r)
            else:
                ahead = np.ones(r)
            prior[i] *= ahead
        prior /= prior.max(axis=1, keepdims=True)
    out = np.empty_like(dist)
    out[order] = d - params.tau * np.log(np.maximum(prior, 1e-300))
    return out


def knn_positions(dist: FloatArray, xy_m: FloatArray, k: int, power: float = 1.0,
                  weight_dist: FloatArray | None = None
                  ) -> tuple[FloatArray, FloatArray, NDArray[np.intp]]:
    """Weighted mean position of the k nearest references of every query.

    Parameters
    ----------
    dist : ndarray, shape (S, R)
        Signal distances (any metric; smaller is closer), or any score that picks the k
        references.
    xy_m : ndarray, shape (R, 2)
        Reference positions (m).
    k : int
        Neighbours (at most R).
    power : float
        Weights ``1 / d ** power`` (0 = plain mean).
    weight_dist : ndarray, shape (S, R), optional
        The distances ``d`` the weights and ``d_mean`` use (default ``dist``): the whole-walk
        match picks the neighbours by :func:`walk_scores` and weighs them by the scan's own
        distances.

    Returns
    -------
    xy : ndarray, shape (S, 2)
        Estimated positions (m).
    d_mean : ndarray, shape (S,)
        Mean distance of the k neighbours (a match score: lower is better).
    nn : ndarray, shape (S, k)
        Indexes of the neighbours, nearest first.
    """
    dist = np.asarray(dist, dtype=np.float64)
    k = int(min(max(k, 1), dist.shape[1]))
    if k < dist.shape[1]:
        nn = np.argpartition(dist, k - 1, axis=1)[:, :k]
    else:
        nn = np.tile(np.arange(dist.shape[1]), (len(dist), 1))
    order = np.argsort(np.take_along_axis(dist, nn, axis=1), axis=1)
    nn = np.take_along_axis(nn, order, 1)
    d = np.take_along_axis(dist if weight_dist is None else
                           np.asarray(weight_dist, dtype=np.float64), nn, axis=1)
    w = 1.0 / np.maximum(d, 1e-9) ** power
    xy = (xy_m[nn] * w[..., None]).sum(axis=1) / w.sum(axis=1, keepdims=True)
    return xy, d.mean(axis=1), nn


def gaussian_loglik(rssi_dbm: FloatArray, mean_dbm: FloatArray, var_db2: FloatArray,
                    detect_p: FloatArray, *, var_floor_db2: float = 9.0,
                    missing_mean_dbm: float = -95.0, missing_var_db2: float = 49.0
                    ) -> FloatArray:
    """Log-likelihood of every scan at every reference point (independent transmitters).

    For a transmitter the scan heard with RSSI ``v``:

    - known at the reference point: ``log p + log N(v; mean, max(var, var_floor))``;
    - not heard there: ``log p + log N(v; missing_mean, missing_var)`` (a weak, wide guess);

    with ``p`` the detection probability at the reference point (``detect_p``, which the
    caller smooths so that it is never 0). Transmitters the scan did not hear add nothing
    (absence is too often a missed sweep to count as evidence).

    Parameters
    ----------
    rssi_dbm : ndarray, shape (S, A)
        Scans; NaN = not heard.
    mean_dbm, var_db2, detect_p : ndarray, shape (R, A)
        Per reference point and transmitter; ``mean_dbm`` NaN where never heard, ``var_db2``
        NaN where unknown (fewer than two samples: ``var_floor_db2`` is used).

    Returns
    -------
    ndarray, shape (S, R)
    """
    heard = np.isfinite(rssi_dbm).astype(np.float64)
    v = np.nan_to_num(np.asarray(rssi_dbm, dtype=np.float64), nan=0.0)
    have = np.isfinite(mean_dbm)
    m = np.where(have, mean_dbm, missing_mean_dbm)
    s2 = np.where(have, np.maximum(np.nan_to_num(var_db2, nan=var_floor_db2), var_floor_db2),
                  missing_var_db2)
    p = np.clip(np.asarray(detect_p, dtype=np.float64), 1e-6, 1.0)
    const = np.log(p) - 0.5 * np.log(2.0 * np.pi * s2) - m ** 2 / (2.0 * s2)
    return heard @ const.T + (v ** 2) @ (-0.5 / s2).T + v @ (m / s2).T
