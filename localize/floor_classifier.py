"""The site bundle's floor model, applied to scans (numpy only).

Fitting lives in :mod:`mapping.floor_model`; this module holds the arithmetic both sides share:
the features of a transmitter in a scan, and a multinomial logistic model
``softmax(coef @ x + intercept)``. Two features (:func:`scan_features`):

- ``level``: ``(rssi + 100) / 100`` clipped to [0, 1] (0 = not heard); Wi-Fi's;
- ``presence``: 1 if heard, else 0. BLE's since November 2026: it reads the same whatever
  offset a phone's RSSI has, and on the real site1 traces it is also better than the level for
  the survey phones themselves (docs/radio.md).

The site bundle stores a model as two tables: ``floor_coef`` (``ap, floor, coef``) and
``floor_intercept`` (``floor, intercept``); its kind (``wifi``, or ``ble`` for a site surveyed
without Wi-Fi) is ``metrics.floor_model.kind``, its feature ``metrics.floor_model.feature``
(``level`` when absent: bundles built before the feature was recorded).
Beside a Wi-Fi model a site bundle may hold a BLE one, ``ble_floor_coef`` and
``ble_floor_intercept`` (bundles built before it have none): :meth:`FloorClassifier.from_bundle`
with ``kind`` picks the model of a kind, :func:`site_floor_models` gives all.
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

__all__ = ["FEATURES", "FloorClassifier", "check_feature", "floor_log_proba",
           "floor_model_kind", "level_features", "scan_features", "site_floor_models"]

COEF_TABLE, INTERCEPT_TABLE = "floor_coef", "floor_intercept"
#: Prefix of the tables of the BLE floor model beside a Wi-Fi one (``ble_floor_coef``, ...).
BLE_PREFIX = "ble_"
KINDS = ("wifi", "ble")
#: The features a floor model can be fitted on (:func:`scan_features`).
FEATURES = ("level", "presence")


def level_features(rssi_dbm: ArrayLike) -> NDArray[np.float64]:
    """``(rssi + 100) / 100`` clipped to [0, 1]; 0 where not heard (NaN). Same shape."""
    r = np.asarray(rssi_dbm, dtype=np.float64)
    return np.clip(np.nan_to_num((r + 100.0) / 100.0, nan=0.0), 0.0, 1.0)


def check_feature(feature: str, error: type[Exception] = LocalizationError) -> None:
    """Raise ``error`` unless ``feature`` is one of :data:`FEATURES`."""
    if feature not in FEATURES:
        raise error(f"floor model feature must be one of {FEATURES}, not {feature!r}")


def scan_features(rssi_dbm: ArrayLike, feature: str = "level") -> NDArray[np.float64]:
    """A floor model's features of RSSI values (dBm, NaN = not heard), same shape:
    :func:`level_features` for ``level``, 1 where heard and 0 elsewhere for ``presence``."""
    check_feature(feature)
    if feature == "level":
        return level_features(rssi_dbm)
    return np.isfinite(np.asarray(rssi_dbm, dtype=np.float64)).astype(np.float64)


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
    feature : str
        What a transmitter in a scan gives the model (:data:`FEATURES`).
    """

    floors: NDArray[np.str_]
    aps: NDArray[np.str_]
    coef: NDArray[np.float64]
    intercept: NDArray[np.float64]
    feature: str = "level"

    def __post_init__(self) -> None:
        check_feature(self.feature)
        if self.coef.shape != (len(self.floors), len(self.aps)) or \
                self.intercept.shape != (len(self.floors),):
            raise LocalizationError(f"floor model: coef {self.coef.shape} / intercept "
                                    f"{self.intercept.shape} do not fit {len(self.floors)} "
                                    f"floors x {len(self.aps)} transmitters")
        object.__setattr__(self, "_index", {a: i for i, a in enumerate(self.aps.tolist())})

    @classmethod
    def from_tables(cls, coef_table: pa.Table, intercept_table: pa.Table,
                    prefix: str = "", feature: str = "level") -> FloorClassifier:
        """From the ``floor_coef`` and ``floor_intercept`` tables (pyarrow) of a site bundle
        (``prefix``: ``ble_`` for the BLE model's, named so in errors) and the model's
        ``feature``."""
        import pyarrow as pa

        from localize.arrow_numpy import numeric_column

        coef_name, intercept_name = prefix + COEF_TABLE, prefix + INTERCEPT_TABLE
        for name, table, cols in ((coef_name, coef_table, ("ap", "floor", "coef")),
                                  (intercept_name, intercept_table, ("floor", "intercept"))):
            missing = [c for c in cols if c not in table.column_names]
            if missing:
                raise LocalizationError(f"table {name!r} lacks columns {missing}")
        try:
            intercept = numeric_column(intercept_table.column("intercept")).astype(np.float64)
            values = numeric_column(coef_table.column("coef")).astype(np.float64)
        except (TypeError, ValueError, pa.ArrowException) as err:  # text where numbers belong
            raise LocalizationError(f"tables {coef_name!r} / {intercept_name!r}: coefficients "
                                    f"are not numbers ({err})") from err
        floors = np.asarray(intercept_table.column("floor").to_pylist(), dtype=object).astype(str)
        order = np.argsort(floors, kind="stable")
        floors = floors[order]
        intercept = intercept[order]
        ap_col = np.asarray(coef_table.column("ap").to_pylist(), dtype=object).astype(str)
        fl_col = np.asarray(coef_table.column("floor").to_pylist(), dtype=object).astype(str)
        aps, a_idx = np.unique(ap_col, return_inverse=True)
        f_idx = np.searchsorted(floors, fl_col)
        if len(fl_col) and (np.any(f_idx >= len(floors))
                            or np.any(floors[np.minimum(f_idx, len(floors) - 1)] != fl_col)):
            raise LocalizationError(f"{coef_name} names floors that {intercept_name} lacks")
        coef = np.zeros((len(floors), len(aps)))
        coef[f_idx, a_idx] = values
        return cls(floors, aps, coef, intercept, feature)

    @classmethod
    def from_bundle(cls, bundle: MapBundle, kind: str | None = None) -> FloorClassifier | None:
        """A floor model of a site bundle; None when the bundle has none (of that kind).

        ``kind`` None: the main model (``floor_coef``, of kind :func:`floor_model_kind`);
        ``"wifi"`` or ``"ble"``: the model over scans of that kind, the main one when it is
        of that kind, else (BLE) the one beside it (``ble_floor_coef``)."""
        if kind is not None and kind not in KINDS:
            raise LocalizationError(f"floor model kind must be one of {KINDS}, not {kind!r}")
        main = floor_model_kind(bundle)
        prefix = "" if kind is None or kind == main else BLE_PREFIX if kind == "ble" else None
        if prefix is None:
            return None
        names = (prefix + COEF_TABLE, prefix + INTERCEPT_TABLE)
        has = [bundle.has_table(n) for n in names]
        metric = "ble_floor_model" if prefix else "floor_model"
        summary = (bundle.manifest.get("metrics") or {}).get(metric)
        announced = isinstance(summary, dict)
        if has[0] != has[1] or announced != has[0]:  # a model is both tables and its metric
            said = [f"table {n}" for n, h in zip(names, has) if h] + (
                [f"metrics.{metric}"] if announced else [])
            lacks = [f"table {n}" for n, h in zip(names, has) if not h] + (
                [] if announced else [f"metrics.{metric}"])
            raise LocalizationError(f"{bundle.path}: incomplete {metric.replace('_', ' ')}: "
                                    f"{' and '.join(said)} without {' and '.join(lacks)} "
                                    "(a damaged or hand-edited site bundle: rebuild it)")
        if not has[0]:
            return None
        try:
            return cls.from_tables(bundle.table(names[0]), bundle.table(names[1]), prefix,
                                   summary.get("feature", "level"))
        except LocalizationError as err:
            raise LocalizationError(f"{bundle.path}: {err}") from err

    def scan_matrix(self, scans: Sequence[RadioScan | None],
                    calibration: tuple[float, float] | None = None) -> NDArray[np.float64]:
        """RSSI of ``scans`` over :attr:`aps`, shape (S, A) (dBm; NaN = not heard), mapped
        through ``calibration`` ``(k, b)`` (``k * rssi + b``) when given: a phone's device
        table entry, as the model's training RSSI was mapped."""
        rssi = scan_rssi_matrix(scans, self._index)
        return rssi if calibration is None else calibration[0] * rssi + calibration[1]

    def log_proba(self, rssi_dbm: ArrayLike) -> NDArray[np.float64]:
        """Log-probability per floor, shape (S, F), of scans as a matrix over :attr:`aps`."""
        return floor_log_proba(scan_features(rssi_dbm, self.feature), self.coef,
                               self.intercept)

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


def floor_model_kind(bundle: MapBundle) -> str:
    """The kind of a site bundle's main floor model (``metrics.floor_model.kind``): ``wifi``
    (also when the manifest does not say), or ``ble`` for a site surveyed without Wi-Fi."""
    fm = (bundle.manifest.get("metrics") or {}).get("floor_model")
    kind = fm.get("kind") if isinstance(fm, dict) else None
    return kind if kind in KINDS else "wifi"


def site_floor_models(bundle: MapBundle) -> dict[str, FloorClassifier]:
    """Kind (``wifi``, ``ble``) -> the site bundle's floor model over scans of that kind; the
    kinds it has no model of are left out (an old site bundle: its main model only)."""
    out = {}
    for kind in KINDS:
        model = FloorClassifier.from_bundle(bundle, kind)
        if model is not None:
            out[kind] = model
    return out
