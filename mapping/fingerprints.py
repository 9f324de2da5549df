"""Fingerprint databases: reference points along the surveyed walks and per-transmitter RSSI
statistics (papers 003/004, eqs. 1-2).

Positioned scans are binned into square cells of ``cell_m`` metres; every cell that holds at
least one scan is a reference point (RP) at the mean position of its scans. Per (RP,
transmitter) the database keeps, over the rows younger than ``max_age_ms``:

- ``mean_dbm``: mean RSSI over the T rows that heard it (eq. 1);
- ``var_db2``: unbiased variance ``sum (rssi - mean)^2 / (T - 1)`` (eq. 2), NaN when T < 2;
- ``n``: T, and ``detection_rate = T / n_scans`` of the RP.

A transmitter an RP never heard has no row: missing stays missing (the papers' 0 and the
baselines' -100 dBm are matcher choices, not stored data). ``cell_m = 0`` makes every scan its
own reference point (the "raw scans" database of the plain kNN baseline).

Tables (see :meth:`FingerprintDB.to_tables`)::

    rp   rp_id int64, x_m, y_m float64 (m), n_scans int64
    fp   rp_id int64, ap str, mean_dbm, var_db2 float64 (dBm, dB^2), n int64,
         detection_rate float64
    meta kind, cell_m, max_age_ms (NaN = no limit), format_version
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from .errors import FingerprintError
from .radio_reduce import IntCodes, KeyedAggregate, TextCodes
from .radio_scans import OBS_COLUMNS, distinct_text

__all__ = [
    "DEFAULT_CELL_M",
    "DEFAULT_MAX_AGE_MS",
    "DenseFingerprints",
    "FingerprintDB",
    "FingerprintSums",
    "build_fingerprints",
]

DEFAULT_CELL_M = 1.0
"""Cell size (m). Measured on site1 (grouped 5-fold by walk, Sorensen kNN): 1 m and 2 m are
equal (3.93 / 3.96 m median), 3 m is worse; 1 m follows the walk lines more closely."""
DEFAULT_MAX_AGE_MS = {"wifi": 6000.0, "ble": None}
"""Stale-row limit per kind (ms). Wi-Fi on site1 (LOWO, Sorensen kNN on raw scans): 3 s 3.90 m,
4 s 3.75, 6 s 3.68, 8 s 3.64 median; 6 s keeps the previous sweep of a scan but little more."""
FORMAT_VERSION = 1


@dataclass(frozen=True)
class DenseFingerprints:
    """A fingerprint database as dense arrays over one list of transmitters.

    Attributes
    ----------
    xy_m : ndarray, shape (R, 2)
        Reference point positions (m).
    n_scans : ndarray, shape (R,)
    aps : ndarray of str, shape (A,)
    mean_dbm, var_db2, detection_rate : ndarray, shape (R, A)
        NaN mean / variance where the RP never heard the transmitter (detection rate 0).
    n : ndarray, shape (R, A)
    """

    xy_m: NDArray[np.float64]
    n_scans: NDArray[np.int64]
    aps: NDArray[np.str_]
    mean_dbm: NDArray[np.float64]
    var_db2: NDArray[np.float64]
    n: NDArray[np.int64]
    detection_rate: NDArray[np.float64]


@dataclass(frozen=True)
class FingerprintDB:
    """Reference points and their per-transmitter statistics (one floor, one kind).

    Attributes
    ----------
    kind : str
        ``"wifi"`` or ``"ble"``.
    rp : DataFrame
        ``rp_id, x_m, y_m, n_scans``.
    fp : DataFrame
        ``rp_id, ap, mean_dbm, var_db2, n, detection_rate`` (long; heard pairs only).
    cell_m : float
        Cell size (m); 0 = one reference point per scan.
    max_age_ms : float or None
        Rows older than this were dropped (ms).
    """

    kind: str
    rp: pd.DataFrame
    fp: pd.DataFrame
    cell_m: float
    max_age_ms: float | None

    @property
    def aps(self) -> NDArray[np.str_]:
        """Transmitters heard anywhere, sorted."""
        return distinct_text(self.fp["ap"])

    def __len__(self) -> int:
        return len(self.rp)

    @cached_property
    def _dense_all(self) -> DenseFingerprints:
        return self._dense(None)

    def dense(self, aps: NDArray[np.str_] | list[str] | None = None) -> DenseFingerprints:
        """Dense arrays over ``aps`` (default: :attr:`aps`, computed once and shared; unknown
        ones stay all-missing). Treat the arrays as read-only."""
        return self._dense_all if aps is None else self._dense(aps)

    def _dense(self, aps: NDArray[np.str_] | list[str] | None) -> DenseFingerprints:
        codes, uniques = pd.factorize(self.fp["ap"].to_numpy(), sort=True)
        uniques = np.asarray(uniques).astype(str)
        if aps is None:
            aps, a_idx = uniques, codes
        else:
            aps = np.asarray(aps).astype(str)
            a_idx = pd.Index(aps).get_indexer(uniques)[codes]
        rp_ids = self.rp["rp_id"].to_numpy()
        fp_rp = self.fp["rp_id"].to_numpy()
        r_idx = np.searchsorted(rp_ids, fp_rp)
        r_idx = np.where((r_idx < len(rp_ids)) & (rp_ids[np.minimum(r_idx, len(rp_ids) - 1)]
                                                  == fp_rp), r_idx, -1)
        ok = (a_idx >= 0) & (r_idx >= 0)
        shape = (len(rp_ids), len(aps))
        mean, var, det = np.full(shape, np.nan), np.full(shape, np.nan), np.zeros(shape)
        n = np.zeros(shape, dtype=np.int64)
        r_idx, a_idx = r_idx[ok], a_idx[ok]
        mean[r_idx, a_idx] = self.fp["mean_dbm"].to_numpy(np.float64)[ok]
        var[r_idx, a_idx] = self.fp["var_db2"].to_numpy(np.float64)[ok]
        n[r_idx, a_idx] = self.fp["n"].to_numpy(np.int64)[ok]
        det[r_idx, a_idx] = self.fp["detection_rate"].to_numpy(np.float64)[ok]
        return DenseFingerprints(self.rp[["x_m", "y_m"]].to_numpy(np.float64),
                                 self.rp["n_scans"].to_numpy(np.int64), aps, mean, var, n, det)

    def restricted(self, aps: NDArray[np.str_] | list[str]) -> FingerprintDB:
        """The same database with only the rows of ``aps`` (after AP selection)."""
        keep = self.fp["ap"].isin(set(np.asarray(aps).astype(str).tolist()))
        return replace(self, fp=self.fp[keep].reset_index(drop=True))

    def at_points(self, keep: NDArray[np.bool_]) -> FingerprintDB:
        """The same database with only the reference points where ``keep`` (shape (R,), in
        :attr:`rp`'s order) is true, and their rows."""
        keep = np.asarray(keep, dtype=bool)
        rp = self.rp[keep].reset_index(drop=True)
        fp = self.fp[self.fp["rp_id"].isin(rp["rp_id"])].reset_index(drop=True)
        return replace(self, rp=rp, fp=fp)

    def to_tables(self) -> dict[str, pd.DataFrame]:
        """``{"rp", "fp", "meta"}`` as plain DataFrames (for Parquet in a bundle)."""
        meta = pd.DataFrame({"kind": [self.kind], "cell_m": [float(self.cell_m)],
                             "max_age_ms": [np.nan if self.max_age_ms is None
                                            else float(self.max_age_ms)],
                             "format_version": [FORMAT_VERSION]})
        return {"rp": self.rp.copy(), "fp": self.fp.copy(), "meta": meta}

    @classmethod
    def from_tables(cls, tables: dict[str, pd.DataFrame]) -> FingerprintDB:
        """Inverse of :meth:`to_tables`; checks columns and references."""
        for name, cols in (("rp", RP_COLUMNS), ("fp", FP_COLUMNS),
                           ("meta", ("kind", "cell_m", "max_age_ms", "format_version"))):
            if name not in tables:
                raise FingerprintError(f"fingerprint tables lack {name!r}")
            missing = [c for c in cols if c not in tables[name].columns]
            if missing:
                raise FingerprintError(f"fingerprint table {name!r} lacks columns {missing}")
        meta = tables["meta"].iloc[0]
        if int(meta["format_version"]) != FORMAT_VERSION:
            raise FingerprintError(f"fingerprint format {meta['format_version']} is not "
                                   f"supported (expected {FORMAT_VERSION})")
        rp, fp = tables["rp"], tables["fp"]
        if not fp["rp_id"].isin(rp["rp_id"]).all():
            raise FingerprintError("fingerprint rows refer to unknown reference points")
        age = float(meta["max_age_ms"])
        return cls(str(meta["kind"]), rp[list(RP_COLUMNS)].reset_index(drop=True),
                   fp[list(FP_COLUMNS)].reset_index(drop=True), float(meta["cell_m"]),
                   None if np.isnan(age) else age)


RP_COLUMNS = ("rp_id", "x_m", "y_m", "n_scans")
FP_COLUMNS = ("rp_id", "ap", "mean_dbm", "var_db2", "n", "detection_rate")


def build_fingerprints(obs: pd.DataFrame, *, kind: str = "wifi",
                       cell_m: float = DEFAULT_CELL_M,
                       max_age_ms: float | None | str = "default") -> FingerprintDB:
    """Fingerprint database of positioned scans.

    Parameters
    ----------
    obs : DataFrame
        Observation table (:func:`~mapping.radio_scans.wifi_observations` /
        :func:`~mapping.radio_scans.ble_observations`) *before* any age filter, so that a scan
        whose rows are all stale still counts in ``n_scans``. Scans without a position are
        ignored.
    kind : {"wifi", "ble"}
    cell_m : float
        Cell size (m); 0 = every scan is a reference point.
    max_age_ms : float, None or "default"
        Rows older than this (ms) are not used; None keeps all; "default" takes
        :data:`DEFAULT_MAX_AGE_MS` of ``kind``.

    Raises
    ------
    FingerprintError
        Missing columns, an unknown kind, a negative cell size, no positioned scan, or no row
        left after the age filter (e.g. a floor without any Wi-Fi).
    """
    sums = FingerprintSums(kind=kind, cell_m=cell_m, max_age_ms=max_age_ms)
    sums.add(obs)
    return sums.result()


_SHIFT_DBM = -70.0
"""RSSI sums are taken of ``rssi - _SHIFT_DBM``: squares stay small, variances exact to
~1e-10 dB^2."""


class FingerprintSums:
    """A fingerprint database built from observation rows added in parts (whole scans at a
    time, e.g. walk by walk): per reference-point cell the scans' position sums and count, per
    (cell, transmitter) the count, sum and sum of squares of RSSI. Memory grows with cells x
    transmitters, never with the rows. Arguments as :func:`build_fingerprints`;
    ``compact_rows``: partial sums held before they are merged."""

    def __init__(self, *, kind: str = "wifi", cell_m: float = DEFAULT_CELL_M,
                 max_age_ms: float | None | str = "default",
                 compact_rows: int = 1_000_000) -> None:
        if kind not in DEFAULT_MAX_AGE_MS:
            raise FingerprintError(f"kind must be one of {sorted(DEFAULT_MAX_AGE_MS)}, "
                                   f"not {kind!r}")
        if not cell_m >= 0:
            raise FingerprintError(f"cell_m must be >= 0, got {cell_m}")
        self.kind, self.cell_m = kind, float(cell_m)
        self.max_age_ms = DEFAULT_MAX_AGE_MS[kind] if isinstance(max_age_ms, str) else max_age_ms
        self.aps = TextCodes()
        self.cells = IntCodes()  # reference-point cells (scan ids with cell_m = 0)
        self._rp = KeyedAggregate(("sx", "sy", "n_scans"),
                                  compact_rows=compact_rows)  # per cell
        self._fp = KeyedAggregate(("n", "s", "q"),
                                  compact_rows=compact_rows)  # per (cell, AP)
        self._rows_used = 0

    def add(self, obs: pd.DataFrame) -> None:
        """Add observation rows (every scan with all its rows in one call). Scans without a
        position are ignored."""
        missing = [c for c in OBS_COLUMNS if c not in obs.columns]
        if missing:
            raise FingerprintError(f"observation table lacks columns {missing}")
        x_m, y_m = obs["x_m"].to_numpy(np.float64), obs["y_m"].to_numpy(np.float64)
        positioned = np.isfinite(x_m) & np.isfinite(y_m)
        if not positioned.any():
            return
        scan_ids = obs["scan_id"].to_numpy(np.int64)[positioned]
        scan_index, first_row = np.unique(scan_ids, return_index=True)
        x, y = x_m[positioned][first_row], y_m[positioned][first_row]
        if self.cell_m > 0:  # (cx, cy) as one key that sorts like the pair
            cx = np.floor(x / self.cell_m).astype(np.int64) + (1 << 30)
            cy = np.floor(y / self.cell_m).astype(np.int64) + (1 << 30)
            if (cx < 0).any() or (cx >= 1 << 31).any() or (cy < 0).any() or (cy >= 1 << 31).any():
                raise FingerprintError(f"positions beyond {self.cell_m * (1 << 30):.3g} m")
            cell_key = (cx << 31) | cy
        else:  # one reference point per scan
            cell_key = scan_index
        cells, cell_of_scan = np.unique(cell_key, return_inverse=True)
        cell_of_scan = cell_of_scan.reshape(-1)
        self._rp.add(cells, sx=np.bincount(cell_of_scan, weights=x, minlength=len(cells)),
                     sy=np.bincount(cell_of_scan, weights=y, minlength=len(cells)),
                     n_scans=np.bincount(cell_of_scan, minlength=len(cells)))
        ap = self.aps.codes(obs["ap"])
        use = positioned & (ap >= 0) & np.isfinite(obs["rssi_dbm"].to_numpy(np.float64))
        if self.max_age_ms is not None:
            use &= obs["age_ms"].to_numpy(np.float64) <= self.max_age_ms
        if not use.any():
            return
        code = self.cells.codes(cells)[cell_of_scan]  # dense code of each scan's cell
        row_cell = code[np.searchsorted(scan_index, obs["scan_id"].to_numpy(np.int64)[use])]
        keys, inv = np.unique((row_cell << 24) | ap[use], return_inverse=True)
        if len(self.aps) > 1 << 24:
            raise FingerprintError("fingerprints: more than 16.7 M transmitters")
        inv = inv.reshape(-1)
        r = obs["rssi_dbm"].to_numpy(np.float64)[use] - _SHIFT_DBM
        self._fp.add(keys, n=np.bincount(inv, minlength=len(keys)),
                     s=np.bincount(inv, weights=r, minlength=len(keys)),
                     q=np.bincount(inv, weights=r * r, minlength=len(keys)))
        self._rows_used += int(use.sum())

    def result(self) -> FingerprintDB:
        """The database of every row added.

        Raises
        ------
        FingerprintError
            No positioned scan, or no row left after the age filter (e.g. a floor without any
            Wi-Fi).
        """
        kind = self.kind
        cells, rp = self._rp.result()  # sorted by cell: rp_id is the rank of the cell
        if len(cells) == 0:
            raise FingerprintError(f"no positioned {kind} scans: cannot build reference points "
                                   f"(a floor without {kind} rows, or rows outside the walks)")
        if self._rows_used == 0:
            raise FingerprintError(f"no {kind} rows younger than {self.max_age_ms} ms among "
                                   f"{int(rp['n_scans'].sum())} positioned scans")
        n_scans = rp["n_scans"]
        rp_table = pd.DataFrame({"rp_id": np.arange(len(cells), dtype=np.int64),
                                 "x_m": rp["sx"] / n_scans, "y_m": rp["sy"] / n_scans,
                                 "n_scans": n_scans})
        keys, fp = self._fp.result()
        rp_of_code = np.searchsorted(cells, self.cells.values())  # cell code -> rp_id
        rp_ids = rp_of_code[keys >> 24]
        ap = keys & ((1 << 24) - 1)
        order = np.lexsort((self.aps.sorted_rank()[ap], rp_ids))  # by RP, then AP name
        rp_ids, ap = rp_ids[order], ap[order]
        n, s, q = fp["n"][order], fp["s"][order], fp["q"][order]
        with np.errstate(invalid="ignore", divide="ignore"):
            var = np.where(n > 1, np.maximum(q - s * s / n, 0.0) / (n - 1), np.nan)  # eq. 2
        stats = pd.DataFrame({"rp_id": rp_ids, "ap": self.aps.names()[ap].astype(object),
                              "mean_dbm": s / n + _SHIFT_DBM, "var_db2": var, "n": n,
                              "detection_rate": np.minimum(n / n_scans[rp_ids], 1.0)})
        stats["ap"] = stats["ap"].astype(str)
        return FingerprintDB(kind, rp_table, stats[list(FP_COLUMNS)], self.cell_m,
                             None if self.max_age_ms is None else float(self.max_age_ms))
