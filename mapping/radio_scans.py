"""Radio observations: Wi-Fi and BLE rows as one long table, and scans as a dense matrix.

Every later step (fingerprints, AP selection, matching, floor model, device calibration) reads
the same *observation* table, one row per (scan, transmitter):

=========  =======  ==============================================================
column     type     meaning
=========  =======  ==============================================================
trace_id   str      walk the scan belongs to ("" when unknown)
scan_id    int64    scan number, unique over the table
t_ms       int64    scan time (Unix ms)
x_m, y_m   float64  position of the scan in the map frame (m); NaN when unknown
ap         str      transmitter: BSSID (Wi-Fi) or ``uuid:major:minor@mac`` (BLE)
rssi_dbm   float64  received signal strength (dBm)
age_ms     float64  scan time minus the transmitter's last-seen time (ms; 0 for BLE)
=========  =======  ==============================================================

Wi-Fi rows come as scans from the reader. BLE sightings arrive one by one; they are grouped
into windows of ``window_ms`` per walk, and a window is one "scan" (mean RSSI per key).

RSSI outside ``rssi_range_dbm`` (default -127..0 dBm, the values a phone can report), or at
0 dBm (a driver's "no reading"), raises :class:`~mapping.errors.FingerprintError` unless
``invalid="drop"``. A transmitter listed twice
in one scan keeps its freshest row (the reader's rule).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from localize.bundle import RSSI_RANGE_DBM
from localize.steps import ble_transmitter_ids

from .errors import FingerprintError

__all__ = ["OBS_COLUMNS", "ScanSet", "ble_observations", "distinct_text", "scan_set",
           "text_codes", "wifi_observations"]

OBS_COLUMNS = ("trace_id", "scan_id", "t_ms", "x_m", "y_m", "ap", "rssi_dbm", "age_ms")


def _need(rows: pd.DataFrame, cols: tuple[str, ...], what: str) -> None:
    missing = [c for c in cols if c not in rows.columns]
    if missing:
        raise FingerprintError(f"{what} rows lack columns {missing}; got {list(rows.columns)}")


def _check_rssi(rssi: NDArray[np.float64], rssi_range_dbm: tuple[float, float], invalid: str,
                what: str) -> NDArray[np.bool_]:
    """Mask of rows to keep: readings within ``rssi_range_dbm`` and not 0 dBm, a driver's "no
    reading" (:func:`localize.bundle.rssi_reading`'s rule, which the trace reader applies
    since session 51: a store ingested before may still hold such rows); raises on the others
    when ``invalid == "raise"``."""
    if invalid not in ("raise", "drop"):
        raise FingerprintError(f"invalid must be 'raise' or 'drop', not {invalid!r}")
    lo, hi = rssi_range_dbm
    ok = np.isfinite(rssi) & (rssi >= lo) & (rssi <= hi) & (rssi != 0)
    if not ok.all() and invalid == "raise":
        bad = rssi[~ok]
        raise FingerprintError(
            f"{what}: {int((~ok).sum())} RSSI values outside [{lo:g}, {hi:g}] dBm or at 0 dBm "
            f"(a driver's 'no reading'; e.g. {bad[:3].tolist()}); pass invalid='drop' to skip "
            "them")
    return ok


def _finish(frame: pd.DataFrame) -> pd.DataFrame:
    frame = frame.sort_values(["scan_id", "ap"], kind="stable").reset_index(drop=True)
    return frame[list(OBS_COLUMNS)]


def _empty() -> pd.DataFrame:
    return pd.DataFrame({"trace_id": pd.Series([], dtype=str),
                         "scan_id": pd.Series([], dtype=np.int64),
                         "t_ms": pd.Series([], dtype=np.int64),
                         "x_m": pd.Series([], dtype=np.float64),
                         "y_m": pd.Series([], dtype=np.float64),
                         "ap": pd.Series([], dtype=str),
                         "rssi_dbm": pd.Series([], dtype=np.float64),
                         "age_ms": pd.Series([], dtype=np.float64)})


def distinct_text(values: pd.Series | NDArray) -> NDArray[np.str_]:
    """Sorted distinct values of a text column (object, string or categorical) as a numpy str
    array, without converting every row (a column can hold millions of rows)."""
    return np.unique(np.asarray(pd.unique(pd.Series(values)), dtype=object).astype(str))


def text_codes(values: pd.Series | NDArray, names: NDArray[np.str_]) -> NDArray[np.int64]:
    """Index of each row's text in ``names`` (-1 where absent or missing), looked up once per
    distinct value (cheap on categorical columns of millions of rows)."""
    codes, uniques = pd.factorize(pd.Series(values))
    lookup = pd.Index(np.asarray(names)).get_indexer(np.asarray(uniques, dtype=object).astype(str))
    return np.append(lookup, -1)[codes]  # code -1 (missing) -> -1


def _lower_ids(ids: pd.Series) -> NDArray[np.object_]:
    """Lower-case ids, each distinct id lower-cased once (cheap on categorical columns)."""
    codes, uniques = pd.factorize(ids)
    return np.array([str(u).lower() for u in uniques], dtype=object)[codes]


def wifi_observations(rows: pd.DataFrame, *, max_age_ms: float | None = None,
                      rssi_range_dbm: tuple[float, float] = RSSI_RANGE_DBM,
                      invalid: str = "raise") -> pd.DataFrame:
    """Observation table of Wi-Fi rows (processed or raw reader rows).

    Parameters
    ----------
    rows : DataFrame
        Columns ``scan_t_ms``, ``bssid``, ``rssi_dbm``; optional ``trace_id``, ``x_m``, ``y_m``
        (m; NaN when absent) and ``age_ms`` (ms; 0 when absent, i.e. all rows fresh).
    max_age_ms : float, optional
        Drop rows older than this (scan time minus last-seen time, ms). None keeps all.
    rssi_range_dbm : (float, float)
        Plausible RSSI range (dBm).
    invalid : {"raise", "drop"}
        What to do with RSSI outside the range (or NaN).

    Returns
    -------
    DataFrame
        The observation table (see the module docstring). A scan whose rows are all older
        than ``max_age_ms`` disappears; use :func:`scan_set` on the unfiltered table when
        empty scans must be kept.
    """
    _need(rows, ("scan_t_ms", "bssid", "rssi_dbm"), "Wi-Fi")
    if len(rows) == 0:
        return _empty()
    n = len(rows)
    trace = (rows["trace_id"].astype(str).to_numpy() if "trace_id" in rows
             else np.full(n, "", dtype=object))
    age = (rows["age_ms"].to_numpy(np.float64) if "age_ms" in rows else np.zeros(n))
    frame = pd.DataFrame({
        "trace_id": trace,
        "t_ms": rows["scan_t_ms"].to_numpy(np.int64),
        "x_m": rows["x_m"].to_numpy(np.float64) if "x_m" in rows else np.full(n, np.nan),
        "y_m": rows["y_m"].to_numpy(np.float64) if "y_m" in rows else np.full(n, np.nan),
        "ap": _lower_ids(rows["bssid"]),
        "rssi_dbm": rows["rssi_dbm"].to_numpy(np.float64),
        "age_ms": np.nan_to_num(age, nan=0.0),
    })
    frame = frame[_check_rssi(frame["rssi_dbm"].to_numpy(), rssi_range_dbm, invalid, "Wi-Fi")]
    if max_age_ms is not None:
        frame = frame[frame["age_ms"] <= max_age_ms]
    frame = frame.sort_values(["trace_id", "t_ms", "ap", "age_ms"], kind="stable")
    frame = frame.drop_duplicates(["trace_id", "t_ms", "ap"], keep="first")
    frame["scan_id"] = frame.groupby(["trace_id", "t_ms"], sort=True).ngroup().astype(np.int64)
    return _finish(frame)


def ble_observations(rows: pd.DataFrame, *, window_ms: int = 2000, key_column: str = "id",
                     rssi_range_dbm: tuple[float, float] = RSSI_RANGE_DBM,
                     invalid: str = "raise") -> pd.DataFrame:
    """Observation table of BLE sightings, grouped into windows that play the part of scans.

    Parameters
    ----------
    rows : DataFrame
        Columns ``t_ms``, ``rssi_dbm`` and ``key_column``; optional ``trace_id``, ``x_m``,
        ``y_m`` (m).
    window_ms : int
        Window length (ms). Windows start at each walk's first sighting.
    key_column : str
        Transmitter id: ``"id"`` (default: ``uuid:major:minor@mac``, see
        :func:`localize.steps.ble_transmitter_ids`; needs ``key`` and, when present, ``mac``),
        ``"key"`` (``uuid:major:minor`` alone) or ``"mac"``.

    Returns
    -------
    DataFrame
        The observation table: one row per (window, key) with the mean RSSI (dBm) of its
        sightings; ``t_ms`` is the window's last sighting, ``x_m, y_m`` the mean position of
        the window's sightings, ``age_ms`` 0.
    """
    if window_ms <= 0:
        raise FingerprintError(f"window_ms must be positive, got {window_ms}")
    _need(rows, ("t_ms", "rssi_dbm", "key" if key_column == "id" else key_column), "BLE")
    if len(rows) == 0:
        return _empty()
    n = len(rows)
    ids = (ble_transmitter_ids(rows["key"].to_numpy(), rows["mac"].fillna("").to_numpy()
                               if "mac" in rows else None)
           if key_column == "id" else rows[key_column].astype(str).str.lower().to_numpy())
    frame = pd.DataFrame({
        "trace_id": (rows["trace_id"].astype(str).to_numpy() if "trace_id" in rows
                     else np.full(n, "", dtype=object)),
        "t_ms": rows["t_ms"].to_numpy(np.int64),
        "x_m": rows["x_m"].to_numpy(np.float64) if "x_m" in rows else np.full(n, np.nan),
        "y_m": rows["y_m"].to_numpy(np.float64) if "y_m" in rows else np.full(n, np.nan),
        "ap": ids,
        "rssi_dbm": rows["rssi_dbm"].to_numpy(np.float64),
    })
    frame = frame[_check_rssi(frame["rssi_dbm"].to_numpy(), rssi_range_dbm, invalid, "BLE")]
    t0 = frame.groupby("trace_id")["t_ms"].transform("min")
    frame["win"] = (frame["t_ms"] - t0) // int(window_ms)
    win = frame.groupby(["trace_id", "win"], sort=True)
    scans = win.agg(t_ms=("t_ms", "max"), x_m=("x_m", "mean"), y_m=("y_m", "mean"))
    scans["scan_id"] = np.arange(len(scans), dtype=np.int64)
    per_key = frame.groupby(["trace_id", "win", "ap"], sort=True)["rssi_dbm"].mean()
    out = per_key.reset_index().join(scans, on=["trace_id", "win"])
    out["age_ms"] = 0.0
    return _finish(out)


@dataclass(frozen=True)
class ScanSet:
    """Scans as a dense matrix over a fixed list of transmitters.

    Attributes
    ----------
    scans : DataFrame
        One row per scan: ``scan_id``, ``trace_id``, ``t_ms``, ``x_m``, ``y_m`` (m, NaN when
        unknown) and ``n_aps`` (transmitters of the scan that are in ``aps``).
    aps : ndarray of str, shape (A,)
        Transmitter ids, sorted.
    rssi_dbm : ndarray, shape (S, A)
        RSSI (dBm); NaN where the scan did not hear the transmitter.
    age_ms : ndarray, shape (S, A)
        Row age (ms); NaN where not heard.
    """

    scans: pd.DataFrame
    aps: NDArray[np.str_]
    rssi_dbm: NDArray[np.float64]
    age_ms: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.scans)

    @property
    def xy_m(self) -> NDArray[np.float64]:
        """Scan positions, shape (S, 2) (m)."""
        return self.scans[["x_m", "y_m"]].to_numpy(np.float64)

    def transformed(self, k: float, b: float) -> ScanSet:
        """A copy with every RSSI mapped to ``k * rssi + b`` (dBm)."""
        return ScanSet(self.scans, self.aps, k * self.rssi_dbm + b, self.age_ms)

    def subset(self, mask: NDArray[np.bool_]) -> ScanSet:
        """The scans where ``mask`` is true."""
        mask = np.asarray(mask, dtype=bool)
        return ScanSet(self.scans[mask].reset_index(drop=True), self.aps, self.rssi_dbm[mask],
                       self.age_ms[mask])


def scan_set(obs: pd.DataFrame, aps: NDArray[np.str_] | list[str] | None = None) -> ScanSet:
    """Dense scans from an observation table.

    Parameters
    ----------
    obs : DataFrame
        Observation table (:func:`wifi_observations`, :func:`ble_observations`).
    aps : array_like of str, optional
        Transmitters to keep (e.g. those of a fingerprint database); rows of other transmitters
        are ignored. Default: every transmitter in ``obs``. A scan that hears none of them is
        kept with an all-NaN row and ``n_aps = 0`` (matchers return NaN for it).
    """
    _need(obs, OBS_COLUMNS, "observation")
    aps = (distinct_text(obs["ap"]) if aps is None
           else np.unique(np.asarray(aps).astype(str)))
    scans = (obs.groupby("scan_id", sort=True)
             .agg(trace_id=("trace_id", "first"), t_ms=("t_ms", "first"),
                  x_m=("x_m", "first"), y_m=("y_m", "first"))
             .reset_index())
    s_idx = np.searchsorted(scans["scan_id"].to_numpy(), obs["scan_id"].to_numpy())
    a_idx = pd.Index(aps).get_indexer(obs["ap"])
    known = a_idx >= 0
    rssi = np.full((len(scans), len(aps)), np.nan)
    age = np.full((len(scans), len(aps)), np.nan)
    rssi[s_idx[known], a_idx[known]] = obs["rssi_dbm"].to_numpy(np.float64)[known]
    age[s_idx[known], a_idx[known]] = obs["age_ms"].to_numpy(np.float64)[known]
    scans["n_aps"] = np.isfinite(rssi).sum(axis=1).astype(np.int64)
    return ScanSet(scans, aps, rssi, age)
