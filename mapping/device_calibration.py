"""Per-device-model RSSI calibration against the reference survey device (paper 003, eq. 5).

``calibrated = k * rssi + b`` maps a phone model's RSSI onto the reference device's scale.

Offline (this module), when a survey has several phone models: every row of the phone is paired
with the nearest row of the reference device for the same transmitter within
``pair_radius_m`` (1 m) on the same floor. Both values of a pair are single readings with the
same physical noise (fading, a little position mismatch), so the reduced-major-axis line
``k = SD(reference) / SD(phone)`` is unbiased where least squares is not (errors in both
variables shrink k by 10-20 %). Pairs are selected on an independent quantity, the mean of the
*other* reference rows within ``select_radius_m``: it must reach ``min_ref_dbm`` (-85 dBm), and
its level on the phone's scale (through the current fit) ``min_device_dbm`` (-88 dBm), because
weak readings are biased upwards by missed detections. Huber weights make the fit robust.
On three simulated sites (5 phones with known distortion) this recovers k within 0.01 and b
within 0.7 dB; binning both phones into cells and regressing cell means was biased by 0.03-0.1
in k (within-cell position mismatch and detection censoring).

Online (an unknown phone, no positions): :func:`localize.rssi_calibration.
estimate_rssi_calibration`, numpy only, which the localizer runs.

The device table (:func:`calibrate_devices`) has one row per model: ``device_model, k, b,
n_pairs, residual_sd_db, method`` with method ``reference``, ``offline`` or ``too_few_pairs``
(k = 1, b = 0). :func:`lookup_calibration` raises a clear error for an unknown model.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from .errors import FingerprintError

__all__ = ["DEVICE_TABLE_COLUMNS", "DeviceCalibration", "calibrate_devices",
           "colocated_pairs", "fit_device_calibration", "lookup_calibration", "rma_fit"]

DEVICE_TABLE_COLUMNS = ("device_model", "k", "b", "n_pairs", "residual_sd_db", "method")


@dataclass(frozen=True)
class DeviceCalibration:
    """``calibrated = k * rssi + b`` for one phone model (dBm).

    Attributes
    ----------
    device_model : str
    k, b : float
    n_pairs : int
        (cell, transmitter) triples the fit used.
    residual_sd_db : float
        Robust SD of the fit residuals (dB), NaN without a fit.
    method : str
        ``reference``, ``offline``, ``online``, ``too_few_pairs`` or ``identity``.
    """

    device_model: str
    k: float
    b: float
    n_pairs: int = 0
    residual_sd_db: float = float("nan")
    method: str = "offline"

    def apply(self, rssi_dbm: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Calibrated RSSI (dBm); NaN stays NaN."""
        return self.k * np.asarray(rssi_dbm, dtype=np.float64) + self.b


def rma_fit(x: NDArray[np.float64], y: NDArray[np.float64], *, huber_c: float = 1.5,
            n_iter: int = 10) -> tuple[float, float, float]:
    """Robust reduced-major-axis fit ``y = k x + b`` (k > 0).

    Returns
    -------
    (k, b, residual_sd)
        ``residual_sd``: robust SD (dB) of ``y - k x - b``.
    """
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    w = np.ones_like(x)
    k, b, sd = 1.0, 0.0, float("nan")
    for _ in range(n_iter):
        mx, my = (w * x).sum() / w.sum(), (w * y).sum() / w.sum()
        vx = (w * (x - mx) ** 2).sum()
        if vx <= 0:
            break
        k = float(np.sqrt((w * (y - my) ** 2).sum() / vx))
        b = float(my - k * mx)
        r = y - k * x - b
        sd = 1.4826 * float(np.median(np.abs(r - np.median(r)))) or 1e-9
        u = np.abs(r) / (huber_c * sd)
        w = np.where(u <= 1, 1.0, 1.0 / np.maximum(u, 1e-12))
    return k, b, sd


def colocated_pairs(device_obs: pd.DataFrame, reference_obs: pd.DataFrame, *,
                    pair_radius_m: float = 1.0, select_radius_m: float = 2.0,
                    max_age_ms: float | None = 3000.0) -> pd.DataFrame:
    """Pairs of readings of the same transmitter by the phone and the reference device.

    Parameters
    ----------
    device_obs, reference_obs : DataFrame
        Positioned observation tables of one floor.
    pair_radius_m : float
        A phone row is paired with the nearest reference row within this distance (m).
    select_radius_m : float
        Radius (m) of the local reference mean used for selecting pairs.
    max_age_ms : float, optional
        Rows older than this are not used (a stale row's RSSI belongs to another place).

    Returns
    -------
    DataFrame
        ``ap, x_dbm`` (phone), ``y_dbm`` (reference), ``local_dbm`` (mean of the other
        reference rows within ``select_radius_m`` of the phone row; NaN with fewer than two).
    """
    def usable(o: pd.DataFrame) -> pd.DataFrame:
        o = o[np.isfinite(o["x_m"].to_numpy(np.float64)) & np.isfinite(o["y_m"].to_numpy())]
        return o if max_age_ms is None else o[o["age_ms"].to_numpy() <= max_age_ms]

    dev, ref = usable(device_obs), usable(reference_obs)
    empty = pd.DataFrame({"ap": pd.Series([], dtype=str), "x_dbm": [], "y_dbm": [],
                          "local_dbm": []})
    if len(dev) == 0 or len(ref) == 0:
        return empty
    aps = pd.Index(np.unique(np.concatenate([dev["ap"].to_numpy().astype(str),
                                             ref["ap"].to_numpy().astype(str)])))
    sep = 1e4 * max(select_radius_m, pair_radius_m)  # keeps transmitters apart in the tree
    ref_pts = np.c_[ref["x_m"], ref["y_m"], aps.get_indexer(ref["ap"]) * sep]
    dev_pts = np.c_[dev["x_m"], dev["y_m"], aps.get_indexer(dev["ap"]) * sep]
    tree = cKDTree(ref_pts)
    dist, j = tree.query(dev_pts, distance_upper_bound=pair_radius_m)
    i = np.flatnonzero(np.isfinite(dist))
    j = j[i]
    if len(i) == 0:
        return empty
    y_all = ref["rssi_dbm"].to_numpy(np.float64)
    near = tree.query_ball_point(dev_pts[i], select_radius_m)
    counts = np.array([len(n) for n in near])
    sums = np.array([y_all[n].sum() for n in near])
    with np.errstate(invalid="ignore", divide="ignore"):
        local = np.where(counts >= 3, (sums - y_all[j]) / (counts - 1), np.nan)
    return pd.DataFrame({"ap": dev["ap"].to_numpy().astype(str)[i],
                         "x_dbm": dev["rssi_dbm"].to_numpy(np.float64)[i],
                         "y_dbm": y_all[j], "local_dbm": local})


def _floor_groups(obs: pd.DataFrame, floor_column: str | None) -> dict[object, pd.DataFrame]:
    if floor_column is None:
        return {None: obs}
    if floor_column not in obs.columns:
        raise FingerprintError(f"observation table has no floor column {floor_column!r}")
    return {f: part for f, part in obs.groupby(floor_column, sort=True)}


def fit_device_calibration(device_obs: pd.DataFrame, reference_obs: pd.DataFrame, *,
                           device_model: str = "", floor_column: str | None = None,
                           pair_radius_m: float = 1.0, select_radius_m: float = 2.0,
                           max_age_ms: float | None = 3000.0, min_ref_dbm: float = -85.0,
                           min_device_dbm: float = -88.0, min_pairs: int = 50
                           ) -> DeviceCalibration:
    """Fit ``calibrated = k * rssi + b`` of one phone model from co-located readings.

    Parameters
    ----------
    device_obs, reference_obs : DataFrame
        Positioned observation tables of the phone model's and of the reference device's
        walks.
    floor_column : str, optional
        Column with the floor name when the tables span several floors (pairs stay within a
        floor; one line is fitted over all pairs).
    pair_radius_m, select_radius_m, max_age_ms : float
        See :func:`colocated_pairs`.
    min_ref_dbm, min_device_dbm : float
        Pair selection (dBm, see the module docstring).
    min_pairs : int
        With fewer selected pairs the result is the identity with method ``too_few_pairs``.
    """
    ref_groups = _floor_groups(reference_obs, floor_column)
    parts = [colocated_pairs(dev, ref_groups[floor], pair_radius_m=pair_radius_m,
                             select_radius_m=select_radius_m, max_age_ms=max_age_ms)
             for floor, dev in _floor_groups(device_obs, floor_column).items()
             if floor in ref_groups]
    parts = [p for p in parts if len(p)]
    pairs = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(
        {"x_dbm": [], "y_dbm": [], "local_dbm": []})
    local = pairs["local_dbm"].to_numpy(np.float64)
    k, b, sd, n = 1.0, 0.0, float("nan"), 0
    for _ in range(4):  # selection depends on the fit: the phone's level of the local mean
        with np.errstate(invalid="ignore"):
            sel = (local >= min_ref_dbm) & ((local - b) / k >= min_device_dbm)
        n = int(sel.sum())
        if n < min_pairs:
            return DeviceCalibration(device_model, 1.0, 0.0, n, float("nan"), "too_few_pairs")
        k, b, sd = rma_fit(pairs["x_dbm"].to_numpy()[sel], pairs["y_dbm"].to_numpy()[sel])
    return DeviceCalibration(device_model, k, b, n, sd, "offline")


def calibrate_devices(obs: pd.DataFrame, device_of: Mapping[str, str] | pd.Series, *,
                      reference_model: str | None = None, floor_column: str | None = None,
                      **fit_kw) -> pd.DataFrame:
    """The device table of a survey's positioned observations.

    Parameters
    ----------
    obs : DataFrame
        Observation table with ``trace_id`` (and ``floor_column`` for several floors).
    device_of : mapping or Series
        Device model per trace id (the store catalog's ``device_model``).
    reference_model : str, optional
        The reference survey device; default: the model with the most scans (on a tie, the
        first by name).
    floor_column : str, optional
        Floor column when ``obs`` spans several floors.
    **fit_kw
        Passed to :func:`fit_device_calibration`.

    Returns
    -------
    DataFrame
        Columns :data:`DEVICE_TABLE_COLUMNS`, one row per model.
    """
    dev = pd.Series(device_of, dtype=object)
    # the model of each row through its walk's code: no row-wise text (millions of rows)
    trace_code, traces = pd.factorize(obs["trace_id"], use_na_sentinel=False)
    model_of_trace = pd.Series(np.asarray(traces, dtype=object)).map(dev)
    if model_of_trace.isna().any():
        unknown = sorted(map(str, np.asarray(traces, dtype=object)[model_of_trace.isna()]))[:5]
        raise FingerprintError(f"no device model for traces {unknown}")
    code_of_trace, models = pd.factorize(model_of_trace.astype(str), sort=True)
    model_code = code_of_trace[trace_code]
    scan_code, scan_ids = pd.factorize(obs["scan_id"])
    pairs = pd.unique(model_code * max(len(scan_ids), 1) + scan_code)
    scans = pd.Series(np.bincount(pairs // max(len(scan_ids), 1), minlength=len(models)),
                      index=np.asarray(models, dtype=str))
    if reference_model is None:
        reference_model = str(scans.sort_values(ascending=False, kind="stable").index[0])
    if reference_model not in scans.index:
        raise FingerprintError(f"reference model {reference_model!r} has no scans; models: "
                               f"{sorted(scans.index)}")
    rows = [DeviceCalibration(reference_model, 1.0, 0.0, 0, 0.0, "reference")]
    others = sorted(set(scans.index) - {reference_model})
    ref = obs[model_code == scans.index.get_loc(reference_model)] if others else None
    for name in others:
        rows.append(fit_device_calibration(obs[model_code == scans.index.get_loc(name)], ref,
                                           device_model=name, floor_column=floor_column,
                                           **fit_kw))
    return pd.DataFrame([{c: getattr(r, c) for c in DEVICE_TABLE_COLUMNS} for r in rows])


def lookup_calibration(table: pd.DataFrame, device_model: str, *,
                       unknown: str = "raise") -> DeviceCalibration:
    """The calibration of ``device_model`` from a device table.

    Parameters
    ----------
    unknown : {"raise", "identity"}
        For a model not in the table: raise :class:`FingerprintError` (naming the known
        models and the online alternative), or return the identity (method ``identity``).
    """
    hit = table[table["device_model"] == device_model]
    if len(hit):
        r = hit.iloc[0]
        return DeviceCalibration(str(r["device_model"]), float(r["k"]), float(r["b"]),
                                 int(r["n_pairs"]), float(r["residual_sd_db"]), str(r["method"]))
    if unknown == "identity":
        return DeviceCalibration(device_model, 1.0, 0.0, 0, float("nan"), "identity")
    raise FingerprintError(
        f"unknown device model {device_model!r}: the device table knows "
        f"{sorted(table['device_model'].astype(str))}; estimate its calibration online "
        f"(localize.rssi_calibration.estimate_rssi_calibration) or use unknown='identity'")
