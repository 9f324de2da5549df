"""Wi-Fi/BLE positions from a bundle's fingerprint tables (numpy only).

The floor bundles written by ``indoormap build`` carry, per radio kind (``wifi``, ``ble``),
the reference-point tables of :mod:`mapping.fingerprints` (``<kind>_rp``, ``<kind>_fp``). This
module turns them into the localizer's :class:`~localize.radio.RadioModel` with indoormap's
default matcher (:func:`mapping.matching.default_matcher`, same kernels from
:mod:`localize.radio_match`): Sorensen distance on the powed representation, references
weighted by their detection rate, every reference point's distance mixed half and half with
its 1 m neighbourhood's, the k = 5 nearest reference points averaged with weights 1/d^4.

A phone whose RSSI scale differs from the survey device is handled by a linear map
``k * rssi + b`` applied to every scan first: from the bundle's device table when its model is
known (:meth:`FingerprintPositioner.for_device`), or estimated online from a few of its scans
(:meth:`FingerprintPositioner.calibrated_online`, the calibration-free search of
:mod:`localize.rssi_calibration`).

A recorded walk can be located as a whole (:meth:`FingerprintPositioner.locate_walk`): each
scan's neighbours are then picked with the prior its walk's other scans give
(:func:`localize.radio_match.walk_scores`).

Missing-transmitter policy: transmitters the bundle does not know are ignored; a scan that
hears none of the bundle's transmitters gives no fix (``None``), and so does one whose
strongest known transmitter reads below :attr:`FingerprintPositioner.min_strongest_dbm`
(-inf by default: no limit; :data:`localize.radio_match.BLE_MIN_STRONGEST_DBM` says why).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.bundle import RADIO_KINDS
from localize.errors import LocalizationError
from localize.radio_match import (
    AGE_DECAY_MS,
    AGE_FRESH_MS,
    ReferenceMotion,
    WalkSmoothing,
    age_weights,
    knn_positions,
    min_strongest_dbm,
    powed,
    reference_neighbours,
    scan_matrices,
    smoothed_distances,
    sorensen_distances,
    too_weak,
    walk_scores,
)
from localize.rssi_calibration import (OnlineCalibration, checked_rssi_calibration,
                                       estimate_rssi_calibration)
from localize.steps import RadioScan

if TYPE_CHECKING:  # annotations only
    import pyarrow as pa

    from localize.bundle import MapBundle

__all__ = ["FingerprintPositioner", "RadioFixes", "fingerprint_kinds"]

RP_TABLE, FP_TABLE, DEVICE_TABLE = "{kind}_rp", "{kind}_fp", "devices"


def fingerprint_kinds(bundle: MapBundle) -> list[str]:
    """Radio kinds (``wifi``, ``ble``) whose fingerprint tables the bundle holds."""
    return [k for k in RADIO_KINDS
            if bundle.has_table(RP_TABLE.format(kind=k)) and bundle.has_table(FP_TABLE.format(
                kind=k))]


@dataclass(frozen=True)
class RadioFixes:
    """Positions of several scans.

    Attributes
    ----------
    xy_m : ndarray, shape (S, 2)
        Estimated positions (m); NaN for scans without a known transmitter.
    sigma_m : ndarray, shape (S,)
        Weighted RMS spread of the k neighbours around the estimate (m), at least 1 m.
    n_known : ndarray, shape (S,)
        Transmitters of the scan the bundle knows.
    distance : ndarray, shape (S,)
        Mean Sorensen distance of the k neighbours (0 = identical, 1 = nothing shared).
    """

    xy_m: NDArray[np.float64]
    sigma_m: NDArray[np.float64]
    n_known: NDArray[np.int64]
    distance: NDArray[np.float64]


@dataclass(frozen=True)
class FingerprintPositioner:
    """Weighted kNN over reference points (see the module docstring).

    Attributes
    ----------
    aps : ndarray of str, shape (A,)
        Transmitter keys, sorted (BSSIDs lower-case, beacon keys ``uuid:major:minor``).
    xy_m : ndarray, shape (R, 2)
        Reference point positions (m).
    mean_dbm, var_db2 : ndarray, shape (R, A)
        Mean RSSI (dBm) and its variance (dB^2); NaN where the reference never heard it.
    detection_rate : ndarray, shape (R, A)
        Share of the reference point's scans that heard the transmitter.
    k : int
        Neighbours averaged.
    weight_power : float
        Neighbour weights ``1 / distance ** weight_power``.
    neighbour_mix, neighbour_sigma_m : float
        Reference distances mixed with their neighbourhood's (Gaussian, m; see
        :func:`localize.radio_match.smoothed_distances`; 0 = off).
    rssi_k, rssi_b : float
        Calibration ``k * rssi + b`` applied to every scan (dBm); identity by default.
    likelihood_sigma_m : float
        Spread (m) of each neighbour's Gaussian in :meth:`likelihood`.
    age_fresh_ms, age_decay_ms : float
        Scan rows older than ``age_fresh_ms`` weigh ``exp(-(age - fresh) / decay)`` (ms; the
        mapping matcher's :data:`~localize.radio_match.AGE_FRESH_MS` and
        :data:`~localize.radio_match.AGE_DECAY_MS`); rows of unknown age weigh 1.
    min_strongest_dbm : float
        A scan whose strongest known transmitter reads below this (dBm, after the
        calibration) is not located (no fix, no likelihood); -inf (the default) locates
        every scan that hears a known transmitter. :meth:`from_bundle` sets
        :data:`~localize.radio_match.BLE_MIN_STRONGEST_DBM` for BLE (-inf by default).
    """

    aps: NDArray[np.str_]
    xy_m: NDArray[np.float64]
    mean_dbm: NDArray[np.float64]
    var_db2: NDArray[np.float64]
    detection_rate: NDArray[np.float64]
    k: int = 5
    weight_power: float = 4.0
    neighbour_mix: float = 0.5
    neighbour_sigma_m: float = 1.0
    rssi_k: float = 1.0
    rssi_b: float = 0.0
    likelihood_sigma_m: float = 3.0
    age_fresh_ms: float = AGE_FRESH_MS
    age_decay_ms: float = AGE_DECAY_MS
    min_strongest_dbm: float = float("-inf")

    def __repr__(self) -> str:  # its size and settings, not its (R, A) tables
        return (f"FingerprintPositioner({len(self.xy_m)} reference points, {len(self.aps)} "
                f"emitters, k={self.k}, rssi_k={self.rssi_k:g}, rssi_b={self.rssi_b:+g} dB)")

    def __post_init__(self) -> None:
        shape = (len(self.xy_m), len(self.aps))
        for name in ("mean_dbm", "var_db2", "detection_rate"):
            if getattr(self, name).shape != shape:
                raise LocalizationError(f"fingerprints: {name} has shape "
                                        f"{getattr(self, name).shape}, expected {shape}")
        if shape[0] == 0:
            raise LocalizationError("fingerprints: no reference point")
        if not 0.0 <= self.neighbour_mix <= 1.0 or self.neighbour_sigma_m <= 0:
            raise LocalizationError("fingerprints: neighbour_mix must lie in [0, 1] and "
                                    "neighbour_sigma_m be positive")
        if not (self.age_fresh_ms >= 0 and self.age_decay_ms > 0):
            raise LocalizationError("fingerprints: age_fresh_ms must be >= 0 and "
                                    "age_decay_ms positive")
        if np.isnan(self.min_strongest_dbm):
            raise LocalizationError("fingerprints: min_strongest_dbm is NaN")
        ref = powed(self.mean_dbm) * self.detection_rate
        object.__setattr__(self, "_ref", ref)
        object.__setattr__(self, "_neighbours", reference_neighbours(
            self.xy_m, self.neighbour_sigma_m) if self.neighbour_mix > 0 else None)
        object.__setattr__(self, "_index", {a: i for i, a in enumerate(self.aps.tolist())})
        object.__setattr__(self, "_motion", ReferenceMotion(self.xy_m))
        # the last single scan's distances: the filter asks likelihood() and locate() of the
        # same scan in one step
        object.__setattr__(self, "_last_single", None)

    # -- construction ------------------------------------------------------------------------
    @classmethod
    def from_tables(cls, rp: pa.Table, fp: pa.Table, **kw) -> FingerprintPositioner:
        """From the ``<kind>_rp`` and ``<kind>_fp`` tables (pyarrow) of a bundle."""
        from localize.arrow_numpy import numeric_column

        need = {"rp": (rp, ("rp_id", "x_m", "y_m")),
                "fp": (fp, ("rp_id", "ap", "mean_dbm", "var_db2", "detection_rate"))}
        for what, (table, cols) in need.items():
            missing = [c for c in cols if c not in table.column_names]
            if missing:
                raise LocalizationError(f"fingerprint table {what!r} lacks columns {missing}")
        rp_id = numeric_column(rp.column("rp_id")).astype(np.int64)
        order = np.argsort(rp_id, kind="stable")
        rp_id = rp_id[order]
        xy = np.column_stack([numeric_column(rp.column("x_m")).astype(np.float64)[order],
                              numeric_column(rp.column("y_m")).astype(np.float64)[order]])
        fp_rp = numeric_column(fp.column("rp_id")).astype(np.int64)
        r_idx = np.searchsorted(rp_id, fp_rp)
        if len(fp_rp) and (np.any(r_idx >= len(rp_id)) or
                           np.any(rp_id[np.minimum(r_idx, len(rp_id) - 1)] != fp_rp)):
            raise LocalizationError("fingerprint rows refer to unknown reference points")
        ap_col = np.asarray(fp.column("ap").to_pylist(), dtype=object).astype(str)
        aps, a_idx = np.unique(ap_col, return_inverse=True)
        shape = (len(rp_id), len(aps))
        mean, var, det = np.full(shape, np.nan), np.full(shape, np.nan), np.zeros(shape)
        mean[r_idx, a_idx] = numeric_column(fp.column("mean_dbm"))
        var[r_idx, a_idx] = numeric_column(fp.column("var_db2"))
        det[r_idx, a_idx] = numeric_column(fp.column("detection_rate"))
        return cls(aps, xy, mean, var, det, **kw)

    @classmethod
    def from_bundle(cls, bundle: MapBundle, kind: str = "wifi", **kw
                    ) -> FingerprintPositioner | None:
        """The positioner of a floor bundle's ``kind`` fingerprints; None when it has none.
        A BLE window needs a beacon at :data:`~localize.radio_match.BLE_MIN_STRONGEST_DBM`
        (-inf by default) or stronger to be located (``min_strongest_dbm`` in ``kw``
        overrides it). A ``kind`` that is neither is a LocalizationError (``"WiFi"`` looked
        like a bundle without fingerprints)."""
        if kind not in RADIO_KINDS:
            raise LocalizationError(f"kind must be one of {', '.join(RADIO_KINDS)}, got "
                                    f"{kind!r}")
        if kind not in fingerprint_kinds(bundle):
            return None
        kw.setdefault("min_strongest_dbm", min_strongest_dbm(kind))
        return cls.from_tables(bundle.table(RP_TABLE.format(kind=kind)),
                               bundle.table(FP_TABLE.format(kind=kind)), **kw)

    def with_calibration(self, k: float, b: float) -> FingerprintPositioner:
        """The same positioner applying ``k * rssi + b`` (dBm) to every scan; ``k`` and ``b``
        within :func:`~localize.rssi_calibration.checked_rssi_calibration`'s limits."""
        k, b = checked_rssi_calibration(k, b)
        return replace(self, rssi_k=k, rssi_b=b)

    def for_device(self, bundle: MapBundle, device_model: str) -> FingerprintPositioner | None:
        """Calibrated with the bundle's device table entry of ``device_model``; None when the
        bundle has no device table or does not know the model (calibrate online instead)."""
        if not bundle.has_table(DEVICE_TABLE):
            return None
        table = bundle.table(DEVICE_TABLE)
        models = np.asarray(table.column("device_model").to_pylist(), dtype=object).astype(str)
        hit = np.flatnonzero(models == str(device_model))
        if len(hit) == 0:
            return None
        i = int(hit[0])
        return self.with_calibration(float(table.column("k")[i].as_py()),
                                     float(table.column("b")[i].as_py()))

    def online_calibration(self, scans: Sequence[RadioScan], **kw) -> OnlineCalibration:
        """Estimate ``k, b`` of an unknown phone from a few of its scans (no positions needed;
        see :func:`localize.rssi_calibration.estimate_rssi_calibration`)."""
        rssi, age = self.scan_matrices(scans, calibrated=False)
        rssi[age > self.age_fresh_ms] = np.nan  # stale rows lag the walker
        return estimate_rssi_calibration(rssi, self.mean_dbm, self.var_db2, **kw)

    def calibrated_online(self, scans: Sequence[RadioScan], **kw) -> FingerprintPositioner:
        """The positioner calibrated from ``scans`` (see :meth:`online_calibration`)."""
        cal = self.online_calibration(scans, **kw)
        return self.with_calibration(cal.k, cal.b)

    # -- matching ----------------------------------------------------------------------------
    def scan_matrices(self, scans: Sequence[RadioScan], *, calibrated: bool = True
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """RSSI of ``scans`` over :attr:`aps`, shape (S, A) (dBm; NaN = not heard), with the
        calibration applied unless ``calibrated=False``, and the rows' ages (ms, same shape;
        NaN = unknown)."""
        rssi, age = scan_matrices(scans, self._index)
        if calibrated and (self.rssi_k != 1.0 or self.rssi_b != 0.0):
            rssi = self.rssi_k * rssi + self.rssi_b
        return rssi, age

    def _query(self, rssi: NDArray[np.float64], age_ms: ArrayLike | None
               ) -> NDArray[np.float64]:
        """Powed scans (S, A), rows down-weighted by age; all zero for a scan whose strongest
        value is below :attr:`min_strongest_dbm` (not located)."""
        q = powed(rssi)
        q[too_weak(rssi, self.min_strongest_dbm)] = 0.0
        if age_ms is None:
            return q
        age = np.asarray(age_ms, dtype=np.float64).reshape(q.shape)
        return q * age_weights(age, self.age_fresh_ms, self.age_decay_ms)

    def _distances(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        """Signal distances of powed scans ``q`` (S, A) to every reference point, (S, R)
        (read-only when ``q`` is one scan: that result is kept for the next call)."""
        last = self._last_single
        if len(q) == 1 and last is not None and np.array_equal(last[0], q):
            return last[1]
        d = sorensen_distances(q, self._ref)
        if self._neighbours is not None:
            d = smoothed_distances(d, self._neighbours, self.neighbour_mix)
        if len(q) == 1:
            d.flags.writeable = False
            object.__setattr__(self, "_last_single", (q.copy(), d))
        return d

    def locate_matrix(self, rssi_dbm: ArrayLike, t_ms: ArrayLike | None = None,
                      smoothing: WalkSmoothing | None = None, *,
                      age_ms: ArrayLike | None = None) -> RadioFixes:
        """Positions of scans given as a matrix over :attr:`aps` (already calibrated), with
        the rows' ages (ms, same shape; None = all fresh).

        With ``smoothing`` the scans are one walk's, taken at ``t_ms`` (ms), and are matched
        together (:func:`localize.radio_match.walk_scores`); else each on its own.
        """
        rssi = np.asarray(rssi_dbm, dtype=np.float64).reshape(-1, len(self.aps))
        n = len(rssi)
        n_known = np.isfinite(rssi).sum(axis=1).astype(np.int64)
        xy, sigma, dist = np.full((n, 2), np.nan), np.full(n, np.nan), np.full(n, np.nan)
        q = self._query(rssi, age_ms)
        ok = q.sum(axis=1) > 0
        if ok.any():
            d = self._distances(q[ok])
            pick = d
            if smoothing is not None:
                if t_ms is None or len(np.asarray(t_ms)) != n:
                    raise LocalizationError(f"walk smoothing needs one time per scan "
                                            f"({n} scans)")
                pick = walk_scores(d, np.asarray(t_ms, dtype=np.float64)[ok], self._motion,
                                   smoothing)
            p, d_mean, nn = knn_positions(pick, self.xy_m, self.k, self.weight_power,
                                          weight_dist=d)
            w = 1.0 / np.maximum(np.take_along_axis(d, nn, axis=1), 1e-9) ** self.weight_power
            spread2 = (((self.xy_m[nn] - p[:, None, :]) ** 2).sum(axis=2) * w).sum(axis=1) \
                / w.sum(axis=1)
            xy[ok], dist[ok] = p, d_mean
            sigma[ok] = np.maximum(np.sqrt(spread2), 1.0)
        return RadioFixes(xy, sigma, n_known, dist)

    def locate_scans(self, scans: Sequence[RadioScan]) -> RadioFixes:
        """Positions of several scans (calibration applied), each on its own."""
        rssi, age = self.scan_matrices(scans)
        return self.locate_matrix(rssi, age_ms=age)

    def locate_walk(self, scans: Sequence[RadioScan],
                    smoothing: WalkSmoothing | None = None) -> RadioFixes:
        """Positions of one walk's scans (calibration applied), matched together: each
        scan's neighbours are picked with the prior from the walk's other scans (both
        directions with the defaults of :class:`WalkSmoothing`; ``direction="forward"`` uses
        the past only). site1: 3.46 m median against 3.65 m scan by scan."""
        t = np.array([s.t_ms for s in scans], dtype=np.float64)
        rssi, age = self.scan_matrices(scans)
        return self.locate_matrix(rssi, t, smoothing or WalkSmoothing(), age_ms=age)

    def locate(self, scan: RadioScan) -> tuple[float, float, float] | None:
        """``(x_m, y_m, sigma_m)`` of one scan, or None when it hears no known transmitter."""
        fix = self.locate_scans([scan])
        if not np.isfinite(fix.xy_m[0, 0]):
            return None
        return float(fix.xy_m[0, 0]), float(fix.xy_m[0, 1]), float(fix.sigma_m[0])

    def likelihood(self, scan: RadioScan, x_m: ArrayLike, y_m: ArrayLike
                   ) -> NDArray[np.float64] | None:
        """Radio likelihood at positions (m): a mixture of Gaussians (``likelihood_sigma_m``)
        at the 2k nearest reference points, weighted ``1 / d ** weight_power``. Keeps the
        alternatives of an ambiguous scan for the particle filter. None when the scan hears no
        known transmitter.
        """
        if self.likelihood_sigma_m <= 0 or scan is None:
            return None
        q = self._query(*self.scan_matrices([scan]))
        if q.sum() <= 0:
            return None
        d = self._distances(q)
        _, _, nn = knn_positions(d, self.xy_m, 2 * self.k, self.weight_power)
        nn = nn[0]
        w = 1.0 / np.maximum(d[0, nn], 1e-9) ** self.weight_power
        w /= w.sum()
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        inv = 1.0 / (2.0 * self.likelihood_sigma_m ** 2)
        dx = x[..., None] - self.xy_m[nn, 0]
        dy = y[..., None] - self.xy_m[nn, 1]
        return (np.exp(-(dx * dx + dy * dy) * inv) * w).sum(axis=-1)
