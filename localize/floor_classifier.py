"""The site bundle's floor model, applied to scans (numpy only).

Fitting lives in :mod:`mapping.floor_model`; this module holds the arithmetic both sides share:
features ``(rssi + 100) / 100`` clipped to [0, 1] (0 = not heard) and a multinomial logistic
model ``softmax(coef @ x + intercept)``. The site bundle stores it as two tables:
``floor_coef`` (``ap, floor, coef``) and ``floor_intercept`` (``floor, intercept``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.errors import LocalizationError
from localize.radio_match import scan_rssi_matrix
from localize.steps import RadioScan

if TYPE_CHECKING:  # annotations only
    import pyarrow as pa

    from localize.bundle import MapBundle

__all__ = ["FloorClassifier", "floor_log_proba", "level_features"]

COEF_TABLE, INTERCEPT_TABLE = "floor_coef", "floor_intercept"


def level_features(rssi_dbm: ArrayLike) -> NDArray[np.float64]:
    """``(rssi + 100) / 100`` clipped to [0, 1]; 0 where not heard (NaN). Same shape."""
    r = np.asarray(rssi_dbm, dtype=np.float64)
    return np.clip(np.nan_to_num((r + 100.0) / 100.0, nan=0.0), 0.0, 1.0)


def floor_log_proba(features: ArrayLike, coef: ArrayLike, intercept: ArrayLike
                    ) -> NDArray[np.float64]:
    """Log-probability of every floor, shape (S, F), from features (S, A), ``coef`` (F, A) and
    ``intercept`` (F,). Rows whose features are all 0 (nothing known heard) are NaN."""
    x = np.asarray(features, dtype=np.float64)
    z = x @ np.asarray(coef, dtype=np.float64).T + np.asarray(intercept, dtype=np.float64)
    z = z - z.max(axis=1, keepdims=True)
    lp = z - np.log(np.exp(z).sum(axis=1, keepdims=True))
    lp[x.sum(axis=1) == 0] = np.nan
    return lp


@dataclass(frozen=True)
class FloorClassifier:
    """Floor of a scan or a sequence of scans.

    Attributes
    ----------
    floors : ndarray of str, shape (F,)
        Floor names.
    aps : ndarray of str, shape (A,)
        Feature transmitters, sorted.
    coef : ndarray, shape (F, A)
    intercept : ndarray, shape (F,)
    """

    floors: NDArray[np.str_]
    aps: NDArray[np.str_]
    coef: NDArray[np.float64]
    intercept: NDArray[np.float64]

    def __post_init__(self) -> None:
        if self.coef.shape != (len(self.floors), len(self.aps)) or \
                self.intercept.shape != (len(self.floors),):
            raise LocalizationError(f"floor model: coef {self.coef.shape} / intercept "
                                    f"{self.intercept.shape} do not fit {len(self.floors)} "
                                    f"floors x {len(self.aps)} transmitters")
        object.__setattr__(self, "_index", {a: i for i, a in enumerate(self.aps.tolist())})

    @classmethod
    def from_tables(cls, coef_table: pa.Table, intercept_table: pa.Table) -> FloorClassifier:
        """From the ``floor_coef`` and ``floor_intercept`` tables (pyarrow) of a site bundle."""
        for name, table, cols in (("floor_coef", coef_table, ("ap", "floor", "coef")),
                                  ("floor_intercept", intercept_table, ("floor", "intercept"))):
            missing = [c for c in cols if c not in table.column_names]
            if missing:
                raise LocalizationError(f"table {name!r} lacks columns {missing}")
        floors = np.asarray(intercept_table.column("floor").to_pylist(), dtype=object).astype(str)
        order = np.argsort(floors, kind="stable")
        floors = floors[order]
        intercept = np.asarray(intercept_table.column("intercept").to_numpy(), np.float64)[order]
        ap_col = np.asarray(coef_table.column("ap").to_pylist(), dtype=object).astype(str)
        fl_col = np.asarray(coef_table.column("floor").to_pylist(), dtype=object).astype(str)
        aps, a_idx = np.unique(ap_col, return_inverse=True)
        f_idx = np.searchsorted(floors, fl_col)
        if len(fl_col) and (np.any(f_idx >= len(floors))
                            or np.any(floors[np.minimum(f_idx, len(floors) - 1)] != fl_col)):
            raise LocalizationError("floor_coef names floors that floor_intercept lacks")
        coef = np.zeros((len(floors), len(aps)))
        coef[f_idx, a_idx] = coef_table.column("coef").to_numpy()
        return cls(floors, aps, coef, intercept)

    @classmethod
    def from_bundle(cls, bundle: MapBundle) -> FloorClassifier | None:
        """The floor model of a site bundle; None when the bundle has none."""
        if not (bundle.has_table(COEF_TABLE) and bundle.has_table(INTERCEPT_TABLE)):
            return None
        return cls.from_tables(bundle.table(COEF_TABLE), bundle.table(INTERCEPT_TABLE))

    def scan_matrix(self, scans: Sequence[RadioScan | None]) -> NDArray[np.float64]:
        """RSSI of ``scans`` over :attr:`aps`, shape (S, A) (dBm; NaN = not heard)."""
        return scan_rssi_matrix(scans, self._index)

    def log_proba(self, rssi_dbm: ArrayLike) -> NDArray[np.float64]:
        """Log-probability per floor, shape (S, F), of scans as a matrix over :attr:`aps`."""
        return floor_log_proba(level_features(rssi_dbm), self.coef, self.intercept)

    def floors_of(self, scans: Sequence[RadioScan | None]) -> NDArray[np.str_]:
        """Floor per scan; ``""`` for a scan without a known transmitter."""
        lp = self.log_proba(self.scan_matrix(scans))
        ok = np.isfinite(lp).all(axis=1)
        out = np.full(len(lp), "", dtype=object)
        out[ok] = self.floors[np.argmax(lp[ok], axis=1)]
        return out.astype(str)

    def floor_of(self, scan: RadioScan | None) -> str | None:
        """Floor of one scan, None without a known transmitter."""
        f = self.floors_of([scan])[0]
        return f or None

