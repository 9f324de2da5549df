"""Online RSSI calibration of an unknown phone from a handful of its scans (numpy only).

Phones report RSSI on different scales; paper 003 (eq. 5) models a second device as a linear map
of the survey device, so ``calibrated = k * rssi + b`` brings a scan onto the fingerprint
database's scale. Without positions the map is found as in the calibration-free paper: search
``(k, b)`` for the value that makes the scans most *consistent* with the database, i.e. that
minimises the expected signal difference of eqs. 9-10 to the best-matching reference point::

    E(s, r) = mean over shared transmitters a of (k * rssi_sa + b - mean_ra)^2 + var_ra

    cost(k, b) = mean over scans s of min over reference points r of E(s, r)

Reference points are pre-selected per scan by the *set* of transmitters heard (Jaccard
similarity), which does not depend on ``(k, b)``. The search runs on ``k`` and on the offset at a
pivot RSSI (``b = pivot * (1 - k) + offset``), which are far less correlated than ``k`` and
``b``: a coarse grid, then a finer one around the best cell.

Search ranges: ``k`` in [0.5, 2.0] and offset in [-25, 25] dB. Paper 003 searched k in
[0.1, 6] and b in [-10, 0] for its phones; phones that report weaker values than the survey
phone need b > 0 (``k = 0.85, b = -8`` is undone by ``k = 1.18, b = +9.4``), so the range is
symmetric, and gains beyond 2x are not seen in practice.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localize.errors import LocalizationError

__all__ = ["OnlineCalibration", "checked_rssi_calibration", "estimate_rssi_calibration"]

FloatArray = NDArray[np.float64]

#: Calibrations a user may give (``k``, and ``|b|`` in dB): far wider than the online search's
#: and any phone's, narrow enough that ``k * rssi + b`` stays a signal level, not +-inf.
GIVEN_K_LIMITS = (0.1, 10.0)
GIVEN_B_LIMIT_DB = 200.0


def checked_rssi_calibration(k: float, b: float) -> tuple[float, float]:
    """``(k, b)`` as floats, or a LocalizationError unless ``k`` lies in
    :data:`GIVEN_K_LIMITS` and ``|b| <= GIVEN_B_LIMIT_DB`` (dB)."""
    k, b = float(k), float(b)
    if not (GIVEN_K_LIMITS[0] <= k <= GIVEN_K_LIMITS[1] and abs(b) <= GIVEN_B_LIMIT_DB):
        raise LocalizationError(
            f"RSSI calibration k = {k:g}, b = {b:g} dB is out of range: k must lie in "
            f"{GIVEN_K_LIMITS[0]:g}-{GIVEN_K_LIMITS[1]:g} and |b| <= {GIVEN_B_LIMIT_DB:g} dB")
    return k, b


@dataclass(frozen=True)
class OnlineCalibration:
    """Result of :func:`estimate_rssi_calibration`.

    Attributes
    ----------
    k, b : float
        ``calibrated = k * rssi + b`` (dBm).
    cost_db2 : float
        Consistency cost at ``(k, b)`` (dB^2, eqs. 9-10).
    identity_cost_db2 : float
        The cost without calibration (k = 1, b = 0).
    n_scans : int
        Scans used (those with at least ``min_shared`` known transmitters).
    """

    k: float
    b: float
    cost_db2: float
    identity_cost_db2: float
    n_scans: int

    def apply(self, rssi_dbm: FloatArray) -> FloatArray:
        """Calibrated RSSI (dBm); NaN stays NaN."""
        return self.k * np.asarray(rssi_dbm, dtype=np.float64) + self.b


def _candidates(heard: NDArray[np.bool_], ref_heard: NDArray[np.bool_], n_ref: int
                ) -> NDArray[np.intp]:
    """Per scan, the ``n_ref`` reference points with the most similar transmitter set."""
    inter = heard.astype(np.float64) @ ref_heard.T.astype(np.float64)
    union = heard.sum(1)[:, None] + ref_heard.sum(1)[None, :] - inter
    jac = inter / np.maximum(union, 1.0)
    n_ref = min(n_ref, ref_heard.shape[0])
    return np.argsort(-jac, axis=1)[:, :n_ref]


def _costs(rssi: FloatArray, mean: FloatArray, var: FloatArray, cand: NDArray[np.intp],
           ks: FloatArray, bs: FloatArray, min_shared: int, noise_ratio: float) -> FloatArray:
    """cost(k, b) for paired arrays ``ks``, ``bs``, shape (C,)."""
    total = np.zeros(len(ks))
    for s in range(len(rssi)):
        cols = np.flatnonzero(np.isfinite(rssi[s]))
        m = mean[cand[s]][:, cols]                      # (M, a)
        v = np.nan_to_num(var[cand[s]][:, cols], nan=0.0)
        shared = np.isfinite(m)
        n_sh = shared.sum(axis=1)
        ok = n_sh >= min_shared
        if not ok.any():
            continue
        m, v, shared, n_sh = m[ok], v[ok], shared[ok], n_sh[ok]
        x = rssi[s, cols]
        mz = np.where(shared, m, 0.0)
        # sum over shared of (k x + b - m)^2, expanded to vectorise over candidates
        sx2 = (shared * x ** 2).sum(1)
        sx = (shared * x).sum(1)
        sxm = (mz * x).sum(1)
        sm = mz.sum(1)
        sm2 = (mz ** 2).sum(1)
        sv = (shared * v).sum(1)
        k, b = ks[:, None], bs[:, None]
        sq = k ** 2 * sx2 + 2 * k * b * sx + b ** 2 * n_sh - 2 * k * sxm - 2 * b * sm + sm2
        scale = (1.0 + noise_ratio) / (k ** 2 + noise_ratio)  # Deming: errors on both sides
        e = (sq * scale + sv) / n_sh                    # (C, M)
        total += e.min(axis=1)
    return total / max(len(rssi), 1)


def estimate_rssi_calibration(rssi_dbm: FloatArray, ref_mean_dbm: FloatArray,
                              ref_var_db2: FloatArray | None = None, *,
                              k_range: tuple[float, float] = (0.5, 2.0),
                              offset_range_db: tuple[float, float] = (-25.0, 25.0),
                              pivot_dbm: float = -70.0, n_candidates: int = 40,
                              min_shared: int = 5, weak_dbm: float | None = None,
                              noise_ratio: float = 1.0) -> OnlineCalibration:
    """Estimate ``calibrated = k * rssi + b`` for an unknown phone from a few of its scans.

    Parameters
    ----------
    rssi_dbm : ndarray, shape (S, A)
        The phone's scans over the database's transmitters (dBm, NaN = not heard). Five to
        ten scans from a short walk are enough in practice.
    ref_mean_dbm : ndarray, shape (R, A)
        Mean RSSI per reference point and transmitter on the survey device's scale (dBm, NaN =
        never heard there).
    ref_var_db2 : ndarray, shape (R, A), optional
        RSSI variance per reference point (dB^2; NaN treated as 0).
    k_range, offset_range_db : (float, float)
        Search ranges of ``k`` and of the offset at ``pivot_dbm``. ``k_range=(1, 1)`` fits
        the offset alone (``b``), as BLE needs (:mod:`localize.walk_radio`).
    n_candidates : int
        Reference points kept per scan by transmitter-set similarity.
    min_shared : int
        A (scan, reference point) pair needs this many shared transmitters; a scan with fewer
        known transmitters is not used.
    weak_dbm : float, optional
        Ignore scan values below this (dBm) before the search (weak values are the most
        distorted by detection limits).
    noise_ratio : float
        Variance of the reference means' error over the variance of a scan value's error. A
        plain least-squares fit of the means on the scan values (ratio -> infinity) shrinks k
        (on site1 to ~0.8 for the survey phone itself); the Deming form
        ``(k x + b - m)^2 / (k^2 + ratio)`` does not. With the default database (1 m cells)
        ratio 1 (orthogonal regression) gave combined slopes 0.99-1.05 and offsets within
        0.4 dB at -70 dBm (medians over walks of site1 F1, F3 and the simulated sample site);
        0.25 gave 1.05-1.12 and up to +2.9 dB.
    Returns
    -------
    OnlineCalibration
        ``k = 1, b = 0`` (and costs NaN) when no scan has ``min_shared`` known transmitters.
    """
    rssi = np.array(rssi_dbm, dtype=np.float64, ndmin=2)
    mean = np.asarray(ref_mean_dbm, dtype=np.float64)
    if mean.ndim != 2 or rssi.shape[1] != mean.shape[1]:
        raise ValueError(f"scans have {rssi.shape[1]} transmitters, the database "
                         f"{mean.shape[1] if mean.ndim == 2 else mean.shape}")
    var = (np.zeros_like(mean) if ref_var_db2 is None
           else np.asarray(ref_var_db2, dtype=np.float64))
    if weak_dbm is not None:
        rssi = np.where(rssi >= weak_dbm, rssi, np.nan)
    heard = np.isfinite(rssi)
    use = heard.sum(axis=1) >= min_shared
    rssi, heard = rssi[use], heard[use]
    if len(rssi) == 0 or mean.shape[0] == 0:
        return OnlineCalibration(1.0, 0.0, float("nan"), float("nan"), len(rssi))
    cand = _candidates(heard, np.isfinite(mean), n_candidates)

    def to_b(k: FloatArray, off: FloatArray) -> FloatArray:
        return pivot_dbm * (1.0 - k) + off

    k_lo, k_hi = k_range
    o_lo, o_hi = offset_range_db
    ks, offs = np.linspace(k_lo, k_hi, 16 if k_hi > k_lo else 1), np.linspace(o_lo, o_hi, 21)
    for _ in range(3):  # coarse grid, then two finer grids around the best cell
        kk, oo = (a.ravel() for a in np.meshgrid(ks, offs, indexing="ij"))
        cost = _costs(rssi, mean, var, cand, kk, to_b(kk, oo), min_shared,
                      noise_ratio)
        i = int(np.argmin(cost))
        dk, do = (ks[1] - ks[0]) if len(ks) > 1 else 0.0, (offs[1] - offs[0])
        ks = np.unique(np.clip(np.linspace(kk[i] - dk, kk[i] + dk, 11), k_lo, k_hi))
        offs = np.clip(np.linspace(oo[i] - do, oo[i] + do, 11), o_lo, o_hi)
    k_best, b_best = float(kk[i]), float(to_b(kk[i], oo[i]))
    ident = float(_costs(rssi, mean, var, cand, np.array([1.0]), np.array([0.0]),
                         min_shared, noise_ratio)[0])
    return OnlineCalibration(k_best, b_best, float(cost[i]), ident, len(rssi))
