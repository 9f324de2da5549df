"""Which transmitters a fingerprint database should keep, and why the others were dropped.

Reasons (an AP can have several; they are joined with ``;`` in the report):

- ``rare``: heard in fewer than ``min_scans`` scans or ``min_walks`` walks (no stable signature);
- ``flat``: heard nearly everywhere with nearly the same mean RSSI (no position information);
- ``hotspot_ssid``: the SSID looks like a phone hotspot (``iPhone``, ``AndroidAP``, ``Redmi``,
  ``HUAWEI Mate``, ``...的iPhone``, Wi-Fi Direct phones, ...);
- ``far_floors``: heard strongly on floors ``far_floor_gap`` or more apart (carried around);
- ``moving``: the places where different walks hear it strongest are far apart;
- ``moved``: between two surveys (UTC days), its RSSI in the cells both visited differs by more
  than ``moved_change_db`` (median over the cells where either heard it strongly).

A locally administered MAC (bit 1 of the first octet) is *reported* (column
``locally_administered``) but is not a reason by default: on site1 65 % of the BSSIDs are
locally administered virtual APs of the mall's own routers (``intime_*``), so the bit alone says
nothing about mobility (``drop_locally_administered=True`` makes it a reason).

Rows without a position or with a non-finite RSSI are left out of the spatial rules. The rules
work on integer codes of the text columns, never on copies of the table or row-wise text.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from .errors import FingerprintError
from .radio_scans import OBS_COLUMNS, distinct_text, split_by, text_codes

__all__ = [
    "HOTSPOT_SSID",
    "APSelection",
    "APSelectionParams",
    "is_locally_administered",
    "select_aps",
]

HOTSPOT_SSID = re.compile(
    r"iphone|androidap|direct-.*android|\bandroid\b|redmi|红米|小米手机|手机$|\bvivo\b|\boppo\b|"
    r"\bhonor\b|huawei (p\d+|mate|nova)|\bmate \d+|galaxy|oneplus|\bpixel\b|的\s*(iphone|手机)|"
    r"'s (iphone|phone|galaxy)|mobile hotspot|personal hotspot", re.IGNORECASE)
"""SSIDs of phone hotspots (matched with ``search``)."""


@dataclass(frozen=True)
class APSelectionParams:
    """Thresholds of :func:`select_aps` (counts, dBm, dB, m)."""

    min_scans: int = 3
    min_walks: int = 2
    flat_coverage: float = 0.9
    flat_std_db: float = 2.0
    flat_cell_m: float = 5.0
    far_floor_gap: int = 3
    far_floor_strong_dbm: float = -75.0
    moving_strong_dbm: float = -65.0
    moving_min_walks: int = 3
    moving_spread_m: float = 45.0
    moving_min_cells: int = 3
    moved_change_db: float = 15.0
    moved_min_scans: int = 3
    drop_locally_administered: bool = False


@dataclass(frozen=True)
class APSelection:
    """Result of :func:`select_aps`.

    Attributes
    ----------
    kept : ndarray of str
        Transmitters to keep, sorted.
    dropped : DataFrame
        One row per dropped transmitter: ``ap``, ``ssid``, ``reason`` (``;``-joined),
        ``detail`` (the numbers behind the reasons), ``n_scans``, ``n_walks``,
        ``locally_administered``.
    """

    kept: NDArray[np.str_]
    dropped: pd.DataFrame

    def summary(self) -> dict[str, int]:
        """Number of dropped transmitters per reason (a transmitter counts once per reason)."""
        out: dict[str, int] = {}
        for reasons in self.dropped["reason"]:
            for r in reasons.split(";"):
                out[r] = out.get(r, 0) + 1
        return dict(sorted(out.items()))


def is_locally_administered(mac: Sequence[str] | NDArray[np.str_]) -> NDArray[np.bool_]:
    """True where the MAC address has the locally-administered bit (0x02 of the first octet)."""
    first = np.array([int(m[:2], 16) if len(m) >= 2 and re.fullmatch(r"[0-9a-fA-F]{2}", m[:2])
                      else 0 for m in np.asarray(mac).astype(str)], dtype=np.int64)
    return (first & 0x02) != 0


@dataclass(frozen=True)
class _Positioned:
    """The positioned rows of an observation table as integer-coded arrays, taken once per
    floor and shared by the spatial rules (views of the table's columns when every row is
    positioned: no copy of the table, no row-wise text).

    ``ap`` indexes the AP list (-1: none), ``walk`` the table's walks (-1: none)."""

    ap: NDArray[np.int64]
    walk: NDArray[np.int64]
    n_walks: int
    x_m: NDArray[np.float64]
    y_m: NDArray[np.float64]
    rssi_dbm: NDArray[np.float64]
    t_ms: NDArray[np.int64]
    scan_id: NDArray[np.int64]

    @classmethod
    def of(cls, obs: pd.DataFrame, aps: NDArray[np.str_]) -> _Positioned:
        x, y = obs["x_m"].to_numpy(np.float64), obs["y_m"].to_numpy(np.float64)
        ok = np.isfinite(x) & np.isfinite(y)
        rows = slice(None) if ok.all() else ok
        walk, walks = pd.factorize(obs["trace_id"])
        return cls(text_codes(obs["ap"], aps)[rows], walk[rows], len(walks), x[rows], y[rows],
                   obs["rssi_dbm"].to_numpy(np.float64)[rows],
                   obs["t_ms"].to_numpy(np.int64)[rows],
                   obs["scan_id"].to_numpy(np.int64)[rows])

    def cells(self, cell_m: float) -> NDArray[np.int64]:
        """Square cell (``cell_m``) of every row as one integer key."""
        return (np.floor(self.x_m / cell_m).astype(np.int64) * 1_000_003
                + np.floor(self.y_m / cell_m).astype(np.int64))


def _peak_spread(pos: _Positioned, aps: NDArray[np.str_], strong_dbm: float,
                 min_walks: int) -> pd.Series:
    """Per AP: median distance (m) of the per-walk strongest positions from their median point,
    over walks whose strongest reading is at least ``strong_dbm`` (NaN with fewer walks)."""
    ap, rssi = pos.ap, pos.rssi_dbm
    rows = np.flatnonzero((ap >= 0) & (pos.walk >= 0) & np.isfinite(rssi))
    if not len(rows):
        return pd.Series(dtype=np.float64)
    key_code, keys = pd.factorize(ap[rows] * pos.n_walks + pos.walk[rows])  # (AP, walk)
    best = np.full(len(keys), -np.inf)
    np.maximum.at(best, key_code, rssi[rows])
    at_best = np.flatnonzero(rssi[rows] == best[key_code])
    _, first = np.unique(key_code[at_best], return_index=True)  # each one's first peak row
    peak = rows[at_best[first]]
    peak = peak[rssi[peak] >= strong_dbm]
    count = np.bincount(ap[peak], minlength=len(aps))
    peak = peak[count[ap[peak]] >= min_walks]
    if len(peak) == 0:
        return pd.Series(dtype=np.float64)
    xy = pd.DataFrame({"x_m": pos.x_m[peak], "y_m": pos.y_m[peak]})
    centre = xy.groupby(ap[peak]).transform("median")
    dist = pd.Series(np.hypot(xy["x_m"] - centre["x_m"], xy["y_m"] - centre["y_m"]))
    spread = dist.groupby(ap[peak]).median()
    return pd.Series(spread.to_numpy(), index=aps[spread.index.to_numpy()])


def _survey_change(pos: _Positioned, aps: NDArray[np.str_], cell_m: float, strong_dbm: float,
                   min_cells: int, min_scans: int) -> pd.Series:
    """Per AP: median |RSSI difference| (dB) between two surveys (UTC days) over the cells
    where both surveys have at least ``min_scans`` scans and either heard it at least
    ``strong_dbm`` ("not heard in any of those scans" = -100 dBm; NaN with fewer than
    ``min_cells`` such cells). A moved AP is loud where it used to be silent."""
    if not len(pos.ap):
        return pd.Series(dtype=np.float64)
    day_code, days = pd.factorize(pos.t_ms // 86_400_000, sort=True)
    if len(days) < 2:
        return pd.Series(dtype=np.float64)
    cell_code, cells = pd.factorize(pos.cells(cell_m))
    n_cells, n_dc = len(cells), len(days) * len(cells)
    dc = day_code * n_cells + cell_code  # (day, cell) of every row
    scan_code, scans = pd.factorize(pos.scan_id)
    pairs = _distinct(dc * len(scans) + scan_code)  # distinct (day, cell, scan)
    good = np.bincount(pairs // len(scans), minlength=n_dc).reshape(len(days), n_cells) \
        >= min_scans
    use = good.reshape(-1)[dc] & (pos.ap >= 0) & np.isfinite(pos.rssi_dbm)
    key_code, keys = pd.factorize(pos.ap[use] * n_dc + dc[use])  # (AP, day, cell) means
    mean = np.bincount(key_code, weights=pos.rssi_dbm[use]) / np.bincount(key_code)
    key_ap, key_day, key_cell = keys // n_dc, keys % n_dc // n_cells, keys % n_cells
    out: dict[str, float] = {}
    for da in range(len(days)):
        for db in range(da + 1, len(days)):
            common = good[da] & good[db]
            if common.sum() < min_cells:
                continue
            in_a = (key_day == da) & common[key_cell]
            in_b = (key_day == db) & common[key_cell]
            if not in_a.any() or not in_b.any():
                continue
            ka = key_ap[in_a] * n_cells + key_cell[in_a]  # (AP, cell)
            kb = key_ap[in_b] * n_cells + key_cell[in_b]
            union = np.union1d(ka, kb)  # (AP, cell) heard on either day
            a, b = np.full(len(union), -100.0), np.full(len(union), -100.0)
            a[np.searchsorted(union, ka)] = mean[in_a]
            b[np.searchsorted(union, kb)] = mean[in_b]
            strong = np.maximum(a, b) >= strong_dbm
            diff = pd.Series(np.abs(a - b)[strong])
            stat = diff.groupby(union[strong] // n_cells).agg(["median", "size"])
            for a_idx, v in stat[stat["size"] >= min_cells]["median"].items():
                name = str(aps[a_idx])
                out[name] = max(out.get(name, 0.0), float(v))
    return pd.Series(out, dtype=np.float64)


def _distinct_per_ap(ap: NDArray[np.int64], values: pd.Series, n_aps: int) -> NDArray[np.int64]:
    """Per AP code (0..n_aps-1; -1 = none): number of distinct non-missing ``values``."""
    code, uniques = pd.factorize(values)
    n = max(len(uniques), 1)
    valid = (ap >= 0) & (code >= 0)
    pairs = _distinct(ap[valid] * n + code[valid])
    return np.bincount(pairs // n, minlength=n_aps)


def _distinct(keys: NDArray[np.int64]) -> NDArray[np.int64]:
    """Sorted distinct values of an integer array, by sorting a copy: on millions of keys this
    needs far less memory than hashing (``np.unique``/``pd.unique``)."""
    k = np.sort(keys)
    return k[np.concatenate(([True], k[1:] != k[:-1]))] if len(k) else k


def _flatness(pos: _Positioned, aps: NDArray[np.str_], cell_m: float) -> pd.DataFrame:
    """Per AP: share of cells (``cell_m``) where it is heard and the SD (dB) of its cell means."""
    valid = (pos.ap >= 0) & np.isfinite(pos.rssi_dbm)
    if not valid.any():
        return pd.DataFrame(columns=["coverage", "std_db"], dtype=np.float64)
    cell_code, cells = pd.factorize(pos.cells(cell_m))
    key_code, keys = pd.factorize(pos.ap[valid] * len(cells) + cell_code[valid])
    mean = np.bincount(key_code, weights=pos.rssi_dbm[valid]) / np.bincount(key_code)
    means = pd.Series(mean).groupby(keys // len(cells))  # per AP, over its cells
    out = pd.DataFrame({"coverage": means.size() / len(cells), "std_db": means.std(ddof=0)})
    return out.set_axis(aps[out.index.to_numpy()], axis=0)


def select_aps(obs: pd.DataFrame, *, ssid: Mapping[str, str] | pd.Series | None = None,
               floor_column: str | None = None, floor_order: Sequence[str] | None = None,
               params: APSelectionParams = APSelectionParams()) -> APSelection:
    """Choose the transmitters of a fingerprint database.

    Parameters
    ----------
    obs : DataFrame
        Observation table (:mod:`mapping.radio_scans`), positioned; several floors may be
        given with a floor column.
    ssid : mapping or Series, optional
        SSID per AP (Wi-Fi); without it the SSID rule is skipped.
    floor_column : str, optional
        Column of ``obs`` with the floor name; enables ``far_floors`` and computes ``flat`` and
        ``moving`` per floor (an AP is dropped if it qualifies on any floor).
    floor_order : sequence of str, optional
        Floors bottom to top (default: sorted floor names) for the floor gap.
    params : APSelectionParams

    Returns
    -------
    APSelection
    """
    missing = [c for c in OBS_COLUMNS if c not in obs.columns]
    if missing:
        raise FingerprintError(f"observation table lacks columns {missing}")
    if floor_column is not None and floor_column not in obs.columns:
        raise FingerprintError(f"observation table has no floor column {floor_column!r}")
    aps = distinct_text(obs["ap"])
    ap_code = text_codes(obs["ap"], aps)
    info = pd.DataFrame(index=pd.Index(aps, name="ap"))
    info["n_scans"] = _distinct_per_ap(ap_code, obs["scan_id"], len(aps))
    info["n_walks"] = _distinct_per_ap(ap_code, obs["trace_id"], len(aps))
    ssid_s = pd.Series(ssid, dtype=object) if ssid is not None else pd.Series(dtype=object)
    info["ssid"] = ssid_s.reindex(info.index).fillna("").astype(str)
    info["locally_administered"] = is_locally_administered(aps)
    reasons: dict[str, list[str]] = {a: [] for a in aps}
    details: dict[str, list[str]] = {a: [] for a in aps}

    def flag(mask: pd.Series, reason: str, text) -> None:
        for a in mask[mask].index:
            reasons[a].append(reason)
            details[a].append(text(a))

    p = params
    flag((info["n_scans"] < p.min_scans) | (info["n_walks"] < p.min_walks), "rare",
         lambda a: f"{info.at[a, 'n_scans']} scans/{info.at[a, 'n_walks']} walks")
    if ssid is not None:
        flag(info["ssid"].map(lambda s: bool(HOTSPOT_SSID.search(s))), "hotspot_ssid",
             lambda a: f"ssid {info.at[a, 'ssid']!r}")
    if p.drop_locally_administered:
        flag(info["locally_administered"], "locally_administered", lambda a: "LAA bit")

    groups = ([(None, obs)] if floor_column is None
              else list(split_by(obs, floor_column).items()))
    for floor, part in groups:
        where = "" if floor is None else f" on {floor}"
        pos = _Positioned.of(part, aps)
        fl = _flatness(pos, aps, p.flat_cell_m).reindex(info.index)
        flag((fl["coverage"] >= p.flat_coverage) & (fl["std_db"] <= p.flat_std_db), "flat",
             lambda a, fl=fl, where=where: f"coverage {fl.at[a, 'coverage']:.2f}, "
                                           f"SD {fl.at[a, 'std_db']:.1f} dB{where}")
        spread = _peak_spread(pos, aps, p.moving_strong_dbm,
                              p.moving_min_walks).reindex(info.index)
        change = _survey_change(pos, aps, p.flat_cell_m, p.moving_strong_dbm,
                                p.moving_min_cells, p.moved_min_scans).reindex(info.index)
        flag(spread > p.moving_spread_m, "moving",
             lambda a, s=spread, where=where: f"walk peaks {s.at[a]:.0f} m apart{where}")
        flag(change > p.moved_change_db, "moved",
             lambda a, c=change, where=where: f"RSSI changed {c.at[a]:.0f} dB between "
                                              f"surveys{where}")
    if floor_column is not None:
        order = (list(floor_order) if floor_order is not None
                 else distinct_text(obs[floor_column]).tolist())
        rank = {str(f): i for i, f in enumerate(order)}  # a repeated name: its last place
        strong = obs["rssi_dbm"].to_numpy(np.float64) >= p.far_floor_strong_dbm
        level = np.append(np.fromiter(rank.values(), np.int64, len(rank)), -1)[
            text_codes(obs[floor_column], np.array(list(rank), dtype=str))][strong]
        known = (level >= 0) & (ap_code[strong] >= 0)  # floors not in floor_order do not count
        span = pd.Series(level[known]).groupby(ap_code[strong][known]).agg(["min", "max"])
        gap = pd.Series((span["max"] - span["min"]).to_numpy(np.float64),
                        index=aps[span.index.to_numpy()]).reindex(info.index)
        flag(gap >= p.far_floor_gap, "far_floors",
             lambda a: f"strong on floors {int(gap.at[a])} apart")

    for a in aps:  # one reason once, in first-seen order
        reasons[a] = list(dict.fromkeys(reasons[a]))
    dropped_aps = [a for a in aps if reasons[a]]
    dropped = pd.DataFrame({
        "ap": pd.Series(dropped_aps, dtype=str),
        "ssid": info.loc[dropped_aps, "ssid"].to_numpy(dtype=str),
        "reason": [";".join(reasons[a]) for a in dropped_aps],
        "detail": ["; ".join(details[a]) for a in dropped_aps],
        "n_scans": info.loc[dropped_aps, "n_scans"].to_numpy(np.int64),
        "n_walks": info.loc[dropped_aps, "n_walks"].to_numpy(np.int64),
        "locally_administered": info.loc[dropped_aps, "locally_administered"].to_numpy(bool),
    })
    kept = np.array([a for a in aps if not reasons[a]], dtype=str)
    return APSelection(kept, dropped)
