"""Fingerprint matchers: weighted kNN and a Gaussian (probabilistic) match.

Both follow the estimator pattern: ``fit(FingerprintDB)`` then ``predict(ScanSet)`` gives a
:class:`MatchResult` with one position per scan. The math is in :mod:`localize.radio_match`
(numpy only, so that the localizer runs the same code).

Missing-transmitter policy
--------------------------
- A transmitter the database does not know is ignored (it carries no position information).
- :class:`WeightedKNN` (powed representation): "not heard" is 0 on both sides, so a transmitter
  heard by the scan but not at a reference point (or the reverse) adds its full powed value to
  the Sorensen numerator -- strong ones weigh a lot, weak ones almost nothing. The reference
  point's value is ``powed(mean) * detection_rate``, the expected powed value of a scan there.
  With ``representation="dbm"`` "not heard" is ``missing_dbm`` on both sides (the plain
  baseline: Euclidean, -100 dBm).
- :class:`GaussianMatch`: a heard transmitter unknown at a reference point is scored with a wide
  Gaussian around ``missing_mean_dbm`` times a small detection probability; transmitters the scan
  did not hear are ignored (see :func:`localize.radio_match.gaussian_loglik`).
- A scan that hears no known transmitter gets position NaN, score NaN, ``n_aps = 0``.

Default: :func:`default_matcher` (weighted kNN, Sorensen on the powed representation, k = 5,
weights 1/d^4, reference distances smoothed over 1 m neighbourhoods): on site1 (walks held out)
it beats the Gaussian match by ~1 m median; see ``benchmarks/wifi_accuracy.py``. For a whole
recorded walk, :func:`default_walk_matcher` matches its scans together (forward-backward over
the reference points; site1: 3.46 m median against 3.65 m per scan).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from localize.radio_match import (
    AGE_DECAY_MS,
    AGE_FRESH_MS,
    ReferenceMotion,
    WalkSmoothing,
    age_weights,
    euclidean_distances,
    gaussian_loglik,
    knn_positions,
    min_strongest_dbm,
    powed,
    reference_neighbours,
    smoothed_distances,
    sorensen_distances,
    too_weak,
    walk_scores,
)

from .errors import FingerprintError
from .fingerprints import DenseFingerprints, FingerprintDB
from .radio_scans import ScanSet

__all__ = ["GaussianMatch", "MatchResult", "WeightedKNN", "align_scans", "default_matcher",
           "default_walk_matcher"]


@dataclass(frozen=True)
class MatchResult:
    """Positions estimated from scans.

    Attributes
    ----------
    xy_m : ndarray, shape (S, 2)
        Position (m); NaN for scans with no known transmitter.
    score : ndarray, shape (S,)
        Match quality: mean signal distance of the k neighbours (kNN, lower is better) or the
        best log-likelihood per heard transmitter (Gaussian, higher is better). NaN as above.
    n_aps : ndarray, shape (S,)
        Transmitters of the scan known to the database.
    neighbours : ndarray, shape (S, k)
        Reference point rows used, best first (-1 for scans without a position).
    """

    xy_m: NDArray[np.float64]
    score: NDArray[np.float64]
    n_aps: NDArray[np.int64]
    neighbours: NDArray[np.intp]


def align_scans(scans: ScanSet, aps: NDArray[np.str_]) -> tuple[NDArray[np.float64],
                                                                 NDArray[np.float64]]:
    """RSSI and age matrices of ``scans`` over the transmitter list ``aps`` (NaN = not heard)."""
    idx = pd.Index(np.asarray(aps)).get_indexer(scans.aps)
    found = idx >= 0
    rssi = np.full((len(scans), len(aps)), np.nan)
    age = np.full((len(scans), len(aps)), np.nan)
    rssi[:, idx[found]] = scans.rssi_dbm[:, found]
    age[:, idx[found]] = scans.age_ms[:, found]
    return rssi, age


def _empty_result(n: int, k: int) -> MatchResult:
    return MatchResult(np.full((n, 2), np.nan), np.full(n, np.nan), np.zeros(n, np.int64),
                       np.full((n, k), -1, dtype=np.intp))


class _Matcher:
    k: int
    min_aps: int
    min_strongest_dbm: float = float("-inf")
    dense_: DenseFingerprints | None = None

    def fit(self, db: FingerprintDB) -> _Matcher:
        """Take the reference points of ``db``."""
        if len(db) == 0 or len(db.fp) == 0:
            raise FingerprintError("cannot fit a matcher on an empty fingerprint database")
        self.dense_ = db.dense()
        self._prepare()
        return self

    def _prepare(self) -> None:  # pragma: no cover - overridden
        pass

    def _dist(self, rssi: NDArray[np.float64], age: NDArray[np.float64]
              ) -> NDArray[np.float64]:  # pragma: no cover - overridden
        raise NotImplementedError

    def _check(self) -> DenseFingerprints:
        if self.dense_ is None:
            raise FingerprintError(f"{type(self).__name__} is not fitted; call fit(db) first")
        return self.dense_

    def predict(self, scans: ScanSet) -> MatchResult:
        """Position of every scan (see :class:`MatchResult`)."""
        dense = self._check()
        rssi, age = align_scans(scans, dense.aps)
        n_aps = np.isfinite(rssi).sum(axis=1).astype(np.int64)
        k = min(self.k, len(dense.xy_m))
        out = _empty_result(len(scans), k)
        ok = (n_aps >= max(self.min_aps, 1)) & ~too_weak(rssi, self.min_strongest_dbm)
        if ok.any():
            cost = self._dist(rssi[ok], age[ok])
            pick = self._pick(cost, scans.scans, ok)
            xy, d, nn = knn_positions(pick, dense.xy_m, k, self._power(), weight_dist=cost)
            out.xy_m[ok], out.neighbours[ok] = xy, nn
            out.score[ok] = self._score(cost, d)
        return MatchResult(out.xy_m, out.score, n_aps, out.neighbours)

    def _power(self) -> float:
        return 0.0

    def _pick(self, cost: NDArray[np.float64], scans: pd.DataFrame, rows: NDArray[np.bool_]
              ) -> NDArray[np.float64]:
        """Scores that pick the k neighbours of the scans ``scans[rows]`` (``cost``, their
        distances, unless the walk is smoothed)."""
        return cost

    def _score(self, cost: NDArray[np.float64], d_mean: NDArray[np.float64]
               ) -> NDArray[np.float64]:
        return d_mean


class WeightedKNN(_Matcher):
    """Weighted k-nearest-neighbour matching.

    Parameters
    ----------
    k : int
        Neighbours averaged.
    weight_power : float
        Neighbour weights ``1 / distance ** weight_power`` (0 = plain mean).
    metric : {"sorensen", "euclidean"}
    representation : {"powed", "dbm"}
        ``powed``: ``((rssi - floor_dbm) / -floor_dbm) ** beta``, 0 when not heard.
        ``dbm``: RSSI with ``missing_dbm`` where not heard (the plain baseline).
    floor_dbm, beta : float
        Powed parameters (dBm, exponent).
    missing_dbm : float
        RSSI assumed for "not heard" with ``representation="dbm"`` (dBm).
    use_detection : bool
        Powed: scale the reference point's value by its detection rate.
    age_fresh_ms, age_decay_ms : float, optional
        If both are given, a query row older than ``age_fresh_ms`` is down-weighted by
        ``exp(-(age - fresh) / decay)`` (powed only).
    neighbour_mix, neighbour_sigma_m : float
        Every reference point's signal distance is mixed with the Gaussian-weighted
        (``neighbour_sigma_m``, m) average over the reference points within 2.5 sigma:
        ``(1 - mix) * own + mix * neighbourhood``
        (:func:`localize.radio_match.smoothed_distances`; 0 = off).
    min_aps : int
        Scans with fewer known transmitters get no position.
    min_strongest_dbm : float
        Scans whose strongest known transmitter reads below this (dBm) get no position
        (:func:`localize.radio_match.too_weak`; -inf = none cut).
    walk_smoothing : WalkSmoothing, optional
        Match the scans of a walk together (:func:`localize.radio_match.walk_scores`): the
        neighbours of a scan are picked with the prior from the walk's other scans (walks by
        the scans' ``trace_id``, order by ``t_ms``) and weighed by the scan's own distances.
    """

    def __init__(self, k: int = 5, *, weight_power: float = 2.0, metric: str = "sorensen",
                 representation: str = "powed", floor_dbm: float = -100.0,
                 beta: float = float(np.e), missing_dbm: float = -100.0,
                 use_detection: bool = True, age_fresh_ms: float | None = None,
                 age_decay_ms: float | None = None, neighbour_mix: float = 0.0,
                 neighbour_sigma_m: float = 1.0, min_aps: int = 1,
                 min_strongest_dbm: float = float("-inf"),
                 walk_smoothing: WalkSmoothing | None = None) -> None:
        if metric not in ("sorensen", "euclidean"):
            raise FingerprintError(f"metric must be 'sorensen' or 'euclidean', not {metric!r}")
        if representation not in ("powed", "dbm"):
            raise FingerprintError(f"representation must be 'powed' or 'dbm', "
                                   f"not {representation!r}")
        if metric == "sorensen" and representation == "dbm":
            raise FingerprintError("the Sorensen distance needs the powed representation")
        if k < 1:
            raise FingerprintError(f"k must be >= 1, got {k}")
        if not 0.0 <= neighbour_mix <= 1.0 or neighbour_sigma_m <= 0:
            raise FingerprintError(f"neighbour_mix must lie in [0, 1] and neighbour_sigma_m be "
                                   f"positive; got {neighbour_mix}, {neighbour_sigma_m}")
        self.neighbour_mix = float(neighbour_mix)
        self.neighbour_sigma_m = float(neighbour_sigma_m)
        self.k, self.weight_power, self.metric = int(k), float(weight_power), metric
        self.representation, self.floor_dbm, self.beta = representation, floor_dbm, beta
        self.missing_dbm, self.use_detection = missing_dbm, use_detection
        self.age_fresh_ms, self.age_decay_ms, self.min_aps = age_fresh_ms, age_decay_ms, min_aps
        self.min_strongest_dbm = float(min_strongest_dbm)
        self.walk_smoothing = walk_smoothing

    def _vectors(self, rssi: NDArray[np.float64], age: NDArray[np.float64] | None
                 ) -> NDArray[np.float64]:
        if self.representation == "dbm":
            return np.where(np.isfinite(rssi), rssi, self.missing_dbm)
        p = powed(rssi, self.floor_dbm, self.beta)
        if age is not None and self.age_fresh_ms is not None and self.age_decay_ms is not None:
            p = p * age_weights(age, self.age_fresh_ms, self.age_decay_ms)
        return p

    def _prepare(self) -> None:
        d = self.dense_
        ref = self._vectors(d.mean_dbm, None)
        if self.representation == "powed" and self.use_detection:
            ref = ref * d.detection_rate
        self.ref_ = ref
        self.neighbours_ = (reference_neighbours(d.xy_m, self.neighbour_sigma_m)
                            if self.neighbour_mix > 0 else None)
        self.motion_ = ReferenceMotion(d.xy_m)  # transitions built on first use

    def _pick(self, cost: NDArray[np.float64], scans: pd.DataFrame, rows: NDArray[np.bool_]
              ) -> NDArray[np.float64]:
        if self.walk_smoothing is None:
            return cost
        out = np.empty_like(cost)
        t = scans["t_ms"].to_numpy(np.float64)[rows]
        walk = scans["trace_id"].to_numpy().astype(str)[rows]
        for w in np.unique(walk):
            mine = np.flatnonzero(walk == w)
            out[mine] = walk_scores(cost[mine], t[mine], self.motion_, self.walk_smoothing)
        return out

    def _dist(self, rssi: NDArray[np.float64], age: NDArray[np.float64]) -> NDArray[np.float64]:
        q = self._vectors(rssi, age)
        if self.metric == "sorensen":
            dist = sorensen_distances(q, self.ref_)
        else:
            dist = euclidean_distances(q, self.ref_)
        if self.neighbours_ is None:
            return dist
        return smoothed_distances(dist, self.neighbours_, self.neighbour_mix)

    def _power(self) -> float:
        return self.weight_power


class GaussianMatch(_Matcher):
    """Probabilistic match: Gaussian RSSI per (reference point, transmitter) with the stored
    mean and variance (variance floored), times the detection probability.

    Parameters
    ----------
    k : int
        The k most likely reference points are averaged (equal weights).
    var_floor_db2 : float
        Smallest variance used (dB^2); also the variance of single-sample pairs.
    missing_mean_dbm, missing_var_db2 : float
        Gaussian for a heard transmitter the reference point never heard (dBm, dB^2).
    detect_prior : (float, float)
        Beta prior (a, b) of the detection probability: ``p = (n + a) / (n_scans + a + b)``.
    min_aps : int
        Scans with fewer known transmitters get no position.
    """

    def __init__(self, k: int = 5, *, var_floor_db2: float = 9.0,
                 missing_mean_dbm: float = -95.0, missing_var_db2: float = 49.0,
                 detect_prior: tuple[float, float] = (1.0, 1.0), min_aps: int = 1) -> None:
        if k < 1:
            raise FingerprintError(f"k must be >= 1, got {k}")
        if var_floor_db2 <= 0 or missing_var_db2 <= 0:
            raise FingerprintError("variances must be positive")
        self.k, self.var_floor_db2 = int(k), float(var_floor_db2)
        self.missing_mean_dbm, self.missing_var_db2 = missing_mean_dbm, missing_var_db2
        self.detect_prior, self.min_aps = detect_prior, min_aps

    def _prepare(self) -> None:
        d = self.dense_
        a, b = self.detect_prior
        self.detect_p_ = (d.n + a) / (d.n_scans[:, None] + a + b)

    def loglik(self, scans: ScanSet) -> NDArray[np.float64]:
        """Log-likelihood of every scan at every reference point, shape (S, R)."""
        dense = self._check()
        rssi, _ = align_scans(scans, dense.aps)
        return self._loglik(rssi)

    def _loglik(self, rssi: NDArray[np.float64]) -> NDArray[np.float64]:
        d = self.dense_
        return gaussian_loglik(rssi, d.mean_dbm, d.var_db2, self.detect_p_,
                               var_floor_db2=self.var_floor_db2,
                               missing_mean_dbm=self.missing_mean_dbm,
                               missing_var_db2=self.missing_var_db2)

    def _dist(self, rssi: NDArray[np.float64], age: NDArray[np.float64]) -> NDArray[np.float64]:
        self._n_heard = np.maximum(np.isfinite(rssi).sum(axis=1), 1)
        return -self._loglik(rssi)

    def _score(self, cost: NDArray[np.float64], d_mean: NDArray[np.float64]
               ) -> NDArray[np.float64]:
        return -cost.min(axis=1) / self._n_heard


def default_matcher(walk_smoothing: WalkSmoothing | None = None, kind: str = "wifi"
                    ) -> WeightedKNN:
    """indoormap's default matcher: Sorensen kNN on the powed representation (k = 5, 1/d^4
    weights, detection-weighted references, each reference point's distance mixed half and
    half with its 1 m neighbourhood's), with rows older than 2.5 s down-weighted with a 4 s
    decay when the scans carry row ages; each scan on its own unless ``walk_smoothing``.
    For ``kind="ble"`` a window whose strongest beacon reads below
    :data:`~localize.radio_match.BLE_MIN_STRONGEST_DBM` (-inf by default: no limit) is not
    located, as in the localizer's
    :class:`~localize.fingerprint_positioner.FingerprintPositioner`."""
    try:
        weakest = min_strongest_dbm(kind)
    except ValueError as err:  # the mapping side's error type
        raise FingerprintError(str(err)) from err
    return WeightedKNN(k=5, weight_power=4.0, age_fresh_ms=AGE_FRESH_MS,
                       age_decay_ms=AGE_DECAY_MS, neighbour_mix=0.5, neighbour_sigma_m=1.0,
                       min_strongest_dbm=weakest, walk_smoothing=walk_smoothing)


def default_walk_matcher() -> WeightedKNN:
    """:func:`default_matcher` matching the scans of each walk together (whole walk, both
    directions; :class:`localize.radio_match.WalkSmoothing` defaults): what ``wifi-locate``
    reports for a recorded walk. The localizer's particle filter takes the per-scan matches
    and combines them with the steps itself."""
    return default_matcher(WalkSmoothing())
