"""Floor classification from Wi-Fi (or BLE) scans, stored as plain arrays (no pickle).

Model: multinomial logistic regression on a feature of each transmitter in a scan
(:func:`localize.floor_classifier.scan_features`): its *level* ``(rssi + 100) / 100`` clipped to
[0, 1], or its *presence* (1 if heard); 0 = not heard. Fitted with scikit-learn (L2, C = 1) and
kept as numpy arrays: ``coef`` (floors x transmitters) and ``intercept`` (floors). Rows of any
age are used (a transmitter heard at all says which floor the phone is on).

The build fits a Wi-Fi model on levels (grouped 5-fold by walk, scans right: site1 (3 floors)
level 100.00 %, presence 99.96 %; simulated sample site level 100 %, presence 92.5 % (a whole
walk wrong); default simulated site 99.73 % / 99.95 %), whose scans should be on the survey
device's RSSI scale (calibrate other phones first), and beside it a BLE model on the 2 s
windows' presence (:mod:`mapping.radio_build`: the floor of walks without Wi-Fi), which any
RSSI offset leaves alone. BLE, walks held out (``benchmarks/wifi_accuracy.py --folds 10``) on
site1: see ``docs/radio.md``.

- one scan: ``softmax(coef @ x + intercept)``;
- a short sequence (the last ``window`` scans of a walk) or a whole walk: the floor with the
  largest sum of per-scan log-probabilities.

A scan that hears no known transmitter gets floor ``""`` and NaN probabilities. Floors without
any scan are left out of the model and listed in ``skipped_floors``.

Tables (:meth:`FloorModel.to_tables`)::

    coef       ap str, floor str, coef float64         (one row per pair, all pairs)
    intercept  floor str, intercept float64
    meta       feature, c, n_scans, n_walks, cv_folds, cv_scan_accuracy, cv_walk_accuracy,
               skipped_floors (";"-joined), format_version
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy import sparse

from localize.floor_classifier import (
    FloorClassifier,
    check_feature,
    floor_log_proba,
    scan_features,
)
from localize.steps import RadioScan

from .errors import FingerprintError
from .matching import align_scans
from .radio_scans import OBS_COLUMNS, ScanSet, distinct_text, scan_set, text_codes

__all__ = ["FloorCV", "FloorModel", "cross_validate_floor_model", "fit_floor_model"]

FORMAT_VERSION = 1


@dataclass(frozen=True)
class FloorCV:
    """Cross-validated floor accuracy (grouped by walk).

    Attributes
    ----------
    scan_accuracy, walk_accuracy, sequence_accuracy : float
        Share of scans / walks / scans-with-their-last-``window``-scans on the right floor.
    n_scans, n_walks, folds, window : int
    confusion : DataFrame
        Scans per (true floor, predicted floor).
    """

    scan_accuracy: float
    walk_accuracy: float
    sequence_accuracy: float
    n_scans: int
    n_walks: int
    folds: int
    window: int
    confusion: pd.DataFrame


@dataclass(frozen=True)
class FloorModel:
    """Per-site floor classifier (see the module docstring).

    Attributes
    ----------
    floors : ndarray of str, shape (F,)
    aps : ndarray of str, shape (A,)
        Feature transmitters, sorted.
    coef : ndarray, shape (F, A)
    intercept : ndarray, shape (F,)
    meta : dict
        ``feature``, ``c``, ``n_scans``, ``n_walks``, ``cv_*``, ``skipped_floors``.
    """

    floors: NDArray[np.str_]
    aps: NDArray[np.str_]
    coef: NDArray[np.float64]
    intercept: NDArray[np.float64]
    meta: dict = field(default_factory=dict)

    def log_proba(self, scans: ScanSet) -> NDArray[np.float64]:
        """Log-probability of every floor per scan, shape (S, F); NaN rows for scans without
        a known transmitter."""
        rssi, _ = align_scans(scans, self.aps)
        return floor_log_proba(scan_features(rssi, self.feature), self.coef, self.intercept)

    @property
    def feature(self) -> str:
        """What a transmitter in a scan gives the model (``level`` or ``presence``)."""
        return str(self.meta.get("feature", "level"))

    def _label(self, lp: NDArray[np.float64]) -> NDArray[np.str_]:
        ok = np.isfinite(lp).all(axis=1)
        out = np.full(len(lp), "", dtype=object)
        if ok.any():
            out[ok] = self.floors[np.argmax(lp[ok], axis=1)]
        return out.astype(str)

    def predict(self, scans: ScanSet) -> NDArray[np.str_]:
        """Floor per scan (``""`` when the scan hears no known transmitter)."""
        return self._label(self.log_proba(scans))

    def predict_sequence(self, scans: ScanSet, window: int = 5) -> NDArray[np.str_]:
        """Floor per scan from the scan and the ``window - 1`` scans before it in its walk
        (same ``trace_id``, by time); scans without a known transmitter add nothing."""
        raw = self.log_proba(scans)
        lp = np.nan_to_num(raw, nan=0.0)
        heard = np.isfinite(raw).all(axis=1).astype(np.float64)
        traces = scans.scans["trace_id"].to_numpy().astype(str)
        order = np.lexsort((scans.scans["t_ms"].to_numpy(), traces))
        trace = traces[order]
        out = np.full((len(lp), lp.shape[1]), np.nan)
        csum = np.cumsum(lp[order], axis=0)
        cnt = np.cumsum(heard[order])
        start = np.searchsorted(trace, trace, side="left")
        lo = np.maximum(np.arange(len(order)) - window + 1, start)
        prev = np.where((lo > 0)[:, None], csum[np.maximum(lo - 1, 0)], 0.0)
        prev_n = np.where(lo > 0, cnt[np.maximum(lo - 1, 0)], 0.0)
        total = csum - prev
        total[(cnt - prev_n) == 0] = np.nan
        out[order] = total
        return self._label(out)

    def predict_walks(self, scans: ScanSet) -> pd.Series:
        """Floor per walk (``trace_id`` index) from all its scans."""
        lp = pd.DataFrame(self.log_proba(scans), columns=self.floors)
        lp["trace_id"] = scans.scans["trace_id"].to_numpy()
        total = lp.groupby("trace_id", sort=True).sum(min_count=1)
        labels = self._label(total.to_numpy(np.float64))
        return pd.Series(labels, index=total.index, name="floor")

    def classifier(self) -> FloorClassifier:
        """The localizer's view of this model (what the site bundle holds)."""
        return FloorClassifier(self.floors, self.aps, self.coef, self.intercept, self.feature)

    def floor_of(self, scan: RadioScan | None) -> str | None:
        """Floor of one scan given as the localizer's ``RadioScan``; None when no
        transmitter is known."""
        return self.classifier().floor_of(scan)

    def to_tables(self) -> dict[str, pd.DataFrame]:
        """``{"coef", "intercept", "meta"}`` as plain DataFrames."""
        f_idx, a_idx = np.meshgrid(np.arange(len(self.floors)), np.arange(len(self.aps)),
                                   indexing="ij")
        coef = pd.DataFrame({"ap": self.aps[a_idx.ravel()], "floor": self.floors[f_idx.ravel()],
                             "coef": self.coef.ravel()})
        intercept = pd.DataFrame({"floor": self.floors, "intercept": self.intercept})
        meta = {**self.meta, "format_version": FORMAT_VERSION}
        meta["skipped_floors"] = ";".join(meta.get("skipped_floors", []))
        return {"coef": coef, "intercept": intercept, "meta": pd.DataFrame([meta])}

    @classmethod
    def from_tables(cls, tables: Mapping[str, pd.DataFrame]) -> FloorModel:
        """Inverse of :meth:`to_tables`."""
        for name, cols in (("coef", ("ap", "floor", "coef")), ("intercept", ("floor",
                                                                          "intercept")),
                           ("meta", ("format_version",))):
            if name not in tables or any(c not in tables[name].columns for c in cols):
                raise FingerprintError(f"floor model table {name!r} is missing or lacks {cols}")
        meta = tables["meta"].iloc[0].to_dict()
        if int(meta.pop("format_version")) != FORMAT_VERSION:
            raise FingerprintError("unsupported floor model format version")
        meta["skipped_floors"] = [f for f in str(meta.get("skipped_floors", "")).split(";") if f]
        check_feature(str(meta.get("feature", "level")), FingerprintError)
        floors = tables["intercept"]["floor"].to_numpy().astype(str)
        coef_t = tables["coef"]
        aps = np.unique(coef_t["ap"].to_numpy().astype(str))
        coef = np.zeros((len(floors), len(aps)))
        f_i = pd.Index(floors).get_indexer(coef_t["floor"].astype(str))
        a_i = pd.Index(aps).get_indexer(coef_t["ap"].astype(str))
        if (f_i < 0).any():
            raise FingerprintError("floor model coefficients name floors without intercept")
        coef[f_i, a_i] = coef_t["coef"].to_numpy(np.float64)
        return cls(floors, aps, coef, tables["intercept"]["intercept"].to_numpy(np.float64),
                   meta)


def _floor_tables(obs_by_floor: Mapping[str, pd.DataFrame]
                  ) -> tuple[dict[str, pd.DataFrame], list[str]]:
    """The non-empty observation tables by floor (checked) and the floors without rows."""
    tables, skipped = {}, []
    for floor, obs in obs_by_floor.items():
        missing = [c for c in OBS_COLUMNS if c not in obs.columns]
        if missing:
            raise FingerprintError(f"floor {floor}: observation table lacks {missing}")
        if len(obs) == 0:
            skipped.append(str(floor))
            continue
        tables[str(floor)] = obs
    if not tables:
        raise FingerprintError("no floor has any scan: cannot fit a floor model")
    return tables, skipped


def _design(tables: Mapping[str, pd.DataFrame], aps: NDArray[np.str_], feature: str
            ) -> tuple[sparse.csr_matrix, NDArray[np.str_], NDArray[np.str_]]:
    """Features (sparse, scans x ``aps``: a scan hears a few dozen of the site's
    transmitters), floor label and walk of every scan of every floor. Built from the long
    observation tables directly: memory grows with the rows, never with scans x transmitters."""
    rows, cols, vals, ys, traces = [], [], [], [], []
    n = 0
    for floor, obs in tables.items():
        scan_idx, scan_ids = pd.factorize(obs["scan_id"], sort=True)
        col = text_codes(obs["ap"], aps)  # per distinct AP, not per row
        value = scan_features(obs["rssi_dbm"].to_numpy(np.float64), feature)
        keep = (col >= 0) & (value > 0)
        rows.append(scan_idx[keep] + n)
        cols.append(col[keep])
        vals.append(value[keep])
        ys.append(np.full(len(scan_ids), floor, dtype=object))
        walk = np.empty(len(scan_ids), dtype=object)
        walk_code, walk_names = pd.factorize(obs["trace_id"], use_na_sentinel=False)
        walk[scan_idx] = np.asarray(walk_names, dtype=object)[walk_code]
        traces.append(walk.astype(str))
        n += len(scan_ids)
    x = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(n, len(aps)))
    return x, np.concatenate(ys).astype(str), np.concatenate(traces)


def _fit_arrays(x: sparse.csr_matrix, y: NDArray[np.str_], c: float
                ) -> tuple[NDArray[np.str_], NDArray[np.float64], NDArray[np.float64]]:
    from sklearn.linear_model import LogisticRegression

    model = LogisticRegression(C=c, max_iter=3000).fit(x, y)
    coef, intercept = model.coef_, model.intercept_
    if len(model.classes_) == 2:  # binary: sklearn keeps one row for the second class
        coef = np.vstack([-coef[0] / 2, coef[0] / 2])
        intercept = np.array([-intercept[0] / 2, intercept[0] / 2])
    return model.classes_.astype(str), coef.astype(np.float64), intercept.astype(np.float64)


def _feature_aps(tables: Mapping[str, pd.DataFrame], min_scans: int) -> NDArray[np.str_]:
    """Transmitters heard in at least ``min_scans`` scans (one observation row per scan and
    transmitter), sorted."""
    counts = pd.concat([o["ap"] for o in tables.values()]).value_counts()
    return np.array(sorted(counts.index[counts >= min_scans]), dtype=str)


def cross_validate_floor_model(obs_by_floor: Mapping[str, pd.DataFrame], *, folds: int = 5,
                               c: float = 1.0, min_scans: int = 3, window: int = 5,
                               seed: int = 0, feature: str = "level") -> FloorCV:
    """Floor accuracy with walks held out (grouped k-fold; walks shuffled with ``seed``).

    Parameters
    ----------
    obs_by_floor : mapping
        Floor name -> observation table (rows of any age).
    folds : int
        Number of folds (at most the number of walks).
    c : float
        Inverse L2 regularisation of the logistic regression.
    min_scans : int
        A transmitter becomes a feature when heard in at least this many training scans.
    window : int
        Scans per sequence for ``sequence_accuracy``.
    feature : str
        ``level`` or ``presence`` (module docstring).
    """
    check_feature(feature, FingerprintError)
    tables, _ = _floor_tables(obs_by_floor)
    walks = distinct_text(pd.concat([o["trace_id"].drop_duplicates() for o in tables.values()]))
    folds = int(min(folds, len(walks)))
    if folds < 2:
        raise FingerprintError("cross-validation needs at least two walks")
    rng = np.random.default_rng(seed)
    fold_of = pd.Series(np.arange(len(walks)) % folds, index=rng.permutation(walks))
    scan_pred, seq_pred, truth, walk_rows = [], [], [], []
    for k in range(folds):
        held = {f: o["trace_id"].isin(fold_of.index[fold_of == k]).to_numpy()
                for f, o in tables.items()}
        train = {f: o[~held[f]] for f, o in tables.items() if (~held[f]).any()}
        model = _fit(train, c=c, min_scans=min_scans, skipped=[], feature=feature)
        for floor, o in tables.items():
            if not held[floor].any():
                continue
            s = scan_set(o[held[floor]])
            scan_pred.append(model.predict(s))
            seq_pred.append(model.predict_sequence(s, window))
            truth.append(np.full(len(s), floor))
            w = model.predict_walks(s)
            walk_rows.append(pd.DataFrame({"trace_id": w.index, "pred": w.to_numpy(),
                                           "floor": floor}))
    truth_a, pred_a, seq_a = (np.concatenate(a) for a in (truth, scan_pred, seq_pred))
    walk = pd.concat(walk_rows, ignore_index=True)
    confusion = pd.crosstab(pd.Series(truth_a, name="floor"), pd.Series(pred_a, name="pred"))
    return FloorCV(float((pred_a == truth_a).mean()), float((walk["pred"] == walk["floor"]).mean()),
                   float((seq_a == truth_a).mean()), len(truth_a), len(walk), folds,
                   window, confusion)


def _fit(tables: Mapping[str, pd.DataFrame], *, c: float, min_scans: int, skipped: list[str],
         feature: str) -> FloorModel:
    aps = _feature_aps(tables, min_scans)
    if len(tables) == 1:  # nothing to tell apart: no design matrix, no regression
        (floor, obs), = tables.items()
        floors, coef, intercept = np.array([floor]), np.zeros((1, len(aps))), np.zeros(1)
        n_scans, walks = obs["scan_id"].nunique(), distinct_text(obs["trace_id"])
    else:
        x, y, walks = _design(tables, aps, feature)
        floors, coef, intercept = _fit_arrays(x, y, c)
        n_scans = len(y)
    meta = {"feature": feature, "c": float(c), "n_scans": int(n_scans),
            "n_walks": len(np.unique(walks)), "skipped_floors": list(skipped)}
    return FloorModel(floors, aps, coef, intercept, meta)


def fit_floor_model(obs_by_floor: Mapping[str, pd.DataFrame], *, c: float = 1.0,
                    min_scans: int = 3, cv_folds: int = 0, window: int = 5,
                    seed: int = 0, feature: str = "level") -> FloorModel:
    """Fit the floor classifier of a site.

    Parameters
    ----------
    obs_by_floor : mapping
        Floor name -> observation table (:mod:`mapping.radio_scans`; rows of any age). A floor
        with an empty table is skipped and listed in ``meta["skipped_floors"]``.
    c, min_scans, window, seed, feature
        See :func:`cross_validate_floor_model`.
    cv_folds : int
        If >= 2, cross-validate first and store the accuracies in ``meta`` (``cv_folds``,
        ``cv_scan_accuracy``, ``cv_walk_accuracy``, ``cv_sequence_accuracy``).

    Raises
    ------
    FingerprintError
        No floor has a scan, or a table lacks columns.
    """
    check_feature(feature, FingerprintError)
    tables, skipped = _floor_tables(obs_by_floor)
    model = _fit(tables, c=c, min_scans=min_scans, skipped=skipped, feature=feature)
    meta = {**model.meta, "cv_folds": 0, "cv_scan_accuracy": np.nan,
            "cv_walk_accuracy": np.nan, "cv_sequence_accuracy": np.nan}
    if cv_folds >= 2 and len(tables) >= 2:
        cv = cross_validate_floor_model(tables, folds=cv_folds, c=c, min_scans=min_scans,
                                        window=window, seed=seed, feature=feature)
        meta.update(cv_folds=cv.folds, cv_scan_accuracy=cv.scan_accuracy,
                    cv_walk_accuracy=cv.walk_accuracy, cv_sequence_accuracy=cv.sequence_accuracy)
    return replace(model, meta=meta)
