"""Wi-Fi/BLE positioning behind a small protocol, and a plain kNN positioner (numpy only).

The filter only needs an object with ``locate(scan) -> (x_m, y_m, sigma_m) | None`` and,
optionally, ``likelihood(scan, x_m, y_m) -> weights``: the fingerprint matcher of the mapping
stage (``mapping/matching.py``) can be plugged in unchanged. :class:`KnnRadioPositioner` is the
stand-in used until then: reference scans (positions and RSSI per transmitter key), Euclidean
distance in dBm over the union of heard keys (unheard = ``missing_dbm``), weighted mean of the k
nearest references. It uses the rows of a scan seen within :data:`KNN_MAX_AGE_MS` (the ILC
findings: 5.5 m -> 4.8 m median for the plain kNN).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.errors import LocalizationError
from localize.steps import RadioScan

__all__ = ["KnnRadioPositioner", "RadioFix", "RadioModel"]

RadioFix = tuple[float, float, float]

#: Rows of a scan older than this (ms) are left out by :class:`KnnRadioPositioner`.
KNN_MAX_AGE_MS = 3000.0


@runtime_checkable
class RadioModel(Protocol):
    """What the localizer asks of a Wi-Fi/BLE positioner."""

    def locate(self, scan: RadioScan) -> RadioFix | None:
        """Position fix ``(x_m, y_m, sigma_m)`` of a scan, or None when it cannot tell."""


class KnnRadioPositioner:
    """k-nearest-neighbour fingerprint positioning.

    Parameters
    ----------
    keys : array_like of str, shape (A,)
        Transmitter keys (BSSIDs, beacon keys), unique.
    xy_m : array_like, shape (R, 2)
        Reference positions (m).
    rssi_dbm : array_like, shape (R, A)
        Mean RSSI per reference and transmitter; NaN = not heard.
    k : int
        Neighbours averaged.
    missing_dbm : float
        RSSI assumed for a transmitter not heard (dBm).
    min_common : int
        A scan needs at least this many known keys to give a fix.
    floor_ids : array_like of str, shape (R,), optional
        Floor of every reference (for :meth:`floor_of`).
    likelihood_k : int
        References in the mixture of :meth:`likelihood`.
    likelihood_sigma_m : float
        Spread of each mixture component (m); 0 disables :meth:`likelihood` (the filter then
        uses a Gaussian around :meth:`locate`).
    """

    def __init__(self, keys: ArrayLike, xy_m: ArrayLike, rssi_dbm: ArrayLike, *, k: int = 5,
                 missing_dbm: float = -100.0, min_common: int = 3,
                 floor_ids: ArrayLike | None = None, likelihood_k: int = 10,
                 likelihood_sigma_m: float = 3.0) -> None:
        self.keys_ = np.asarray(keys).astype(str)
        self.xy_ = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        r = np.asarray(rssi_dbm, dtype=np.float64)
        if r.shape != (len(self.xy_), len(self.keys_)):
            raise LocalizationError(f"rssi_dbm has shape {r.shape}, expected "
                                    f"({len(self.xy_)}, {len(self.keys_)})")
        if len(self.xy_) == 0:
            raise LocalizationError("a radio positioner needs at least one reference")
        if len(np.unique(self.keys_)) != len(self.keys_):
            raise LocalizationError("transmitter keys must be unique")
        self.k = int(k)
        self.missing_dbm = float(missing_dbm)
        self.min_common = int(min_common)
        self.rssi_ = np.where(np.isfinite(r), r, self.missing_dbm).astype(np.float32)
        self._index = {key: i for i, key in enumerate(self.keys_)}
        self.floor_ids_ = None if floor_ids is None else np.asarray(floor_ids).astype(str)
        self.likelihood_k = int(likelihood_k)
        self.likelihood_sigma_m = float(likelihood_sigma_m)

    @classmethod
    def from_scans(cls, xy_m: ArrayLike, scans: list[RadioScan], **kw) -> KnnRadioPositioner:
        """References from scans taken at known positions (one reference per scan)."""
        scans = [s.fresh(KNN_MAX_AGE_MS) for s in scans]
        keys = sorted({k for s in scans for k in s.keys.tolist()})
        index = {k: i for i, k in enumerate(keys)}
        r = np.full((len(scans), len(keys)), np.nan)
        for i, s in enumerate(scans):
            r[i, [index[k] for k in s.keys.tolist()]] = s.rssi_dbm
        return cls(keys, xy_m, r, **kw)

    def _vector(self, scan: RadioScan) -> tuple[NDArray[np.float32], int]:
        scan = scan.fresh(KNN_MAX_AGE_MS)
        v = np.full(len(self.keys_), self.missing_dbm, dtype=np.float32)
        idx = [self._index.get(k, -1) for k in scan.keys.tolist()]
        idx = np.asarray(idx, dtype=np.int64)
        known = idx >= 0
        v[idx[known]] = np.asarray(scan.rssi_dbm, dtype=np.float32)[known]
        return v, int(known.sum())

    def neighbours(self, scan: RadioScan, k: int | None = None
                   ) -> tuple[NDArray[np.intp], NDArray[np.float64]] | None:
        """Indexes and distances (dB) of the k nearest references, or None."""
        if scan is None or len(scan) == 0:
            return None
        v, n_known = self._vector(scan)
        if n_known < self.min_common:
            return None
        d = np.sqrt(((self.rssi_ - v[None, :]) ** 2).sum(axis=1))
        k = min(self.k if k is None else int(k), len(d))
        nn = np.argpartition(d, k - 1)[:k]
        return nn, d[nn]

    def locate(self, scan: RadioScan) -> RadioFix | None:
        """``(x_m, y_m, sigma_m)``: inverse-distance weighted mean of the k nearest references;
        sigma is their RMS spread around it (at least 1 m). None without enough known keys."""
        got = self.neighbours(scan)
        if got is None:
            return None
        nn, d = got
        w = 1.0 / np.maximum(d, 1e-6)
        p = (self.xy_[nn] * w[:, None]).sum(axis=0) / w.sum()
        spread = float(np.sqrt((((self.xy_[nn] - p) ** 2).sum(axis=1) * w).sum() / w.sum()))
        return float(p[0]), float(p[1]), max(spread, 1.0)

    def likelihood(self, scan: RadioScan, x_m: ArrayLike, y_m: ArrayLike
                   ) -> NDArray[np.float64] | None:
        """Radio likelihood at positions: a mixture of Gaussians (``likelihood_sigma_m``) at
        the k nearest references, weighted by inverse signal distance.

        Unlike a single fix it keeps the alternatives of an ambiguous scan (two places that
        look alike), and the particle filter picks the one its motion agrees with. None when
        the scan has too few known transmitters.
        """
        if self.likelihood_sigma_m <= 0:
            return None
        got = self.neighbours(scan, k=self.likelihood_k)
        if got is None:
            return None
        nn, d = got
        w = 1.0 / np.maximum(d, 1e-6)
        w /= w.sum()
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        inv = 1.0 / (2.0 * self.likelihood_sigma_m ** 2)
        out = np.zeros(np.broadcast(x, y).shape)
        for (rx, ry), wk in zip(self.xy_[nn], w):
            out += wk * np.exp(-((x - rx) ** 2 + (y - ry) ** 2) * inv)
        return out

    def floor_of(self, scan: RadioScan) -> str | None:
        """Majority floor of the k nearest references (None without floors or a fix)."""
        if self.floor_ids_ is None:
            return None
        got = self.neighbours(scan)
        if got is None:
            return None
        vals, counts = np.unique(self.floor_ids_[got[0]], return_counts=True)
        return str(vals[np.argmax(counts)])
