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
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from .errors import FingerprintError
from .radio_scans import OBS_COLUMNS, distinct_text, split_by

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


def _peak_spread(obs: pd.DataFrame, strong_dbm: float, min_walks: int) -> pd.Series:
    """Per AP: median distance (m) of the per-walk strongest positions from their median point,
    over walks whose strongest reading is at least ``strong_dbm`` (NaN with fewer walks)."""
    pos = obs[np.isfinite(obs["x_m"]) & np.isfinite(obs["y_m"])]
    if len(pos) == 0:
        return pd.Series(dtype=np.float64)
    peak = pos.loc[pos.groupby(["ap", "trace_id"], sort=False)["rssi_dbm"].idxmax()]
    peak = peak[peak["rssi_dbm"] >= strong_dbm]
    count = peak.groupby("ap")["trace_id"].size()
    peak = peak[peak["ap"].isin(count[count >= min_walks].index)]
    if len(peak) == 0:
        return pd.Series(dtype=np.float64)
    centre = peak.groupby("ap")[["x_m", "y_m"]].transform("median")
    dist = np.hypot(peak["x_m"] - centre["x_m"], peak["y_m"] - centre["y_m"])
    return dist.groupby(peak["ap"]).median()


def _survey_change(obs: pd.DataFrame, cell_m: float, strong_dbm: float, min_cells: int,
                   min_scans: int) -> pd.Series:
    """Per AP: median |RSSI difference| (dB) between two surveys (UTC days) over the cells
    where both surveys have at least ``min_scans`` scans and either heard it at least
    ``strong_dbm`` ("not heard in any of those scans" = -100 dBm; NaN with fewer than
    ``min_cells`` such cells). A moved AP is loud where it used to be silent."""
    pos = obs[np.isfinite(obs["x_m"]) & np.isfinite(obs["y_m"])]
    if len(pos) == 0:
        return pd.Series(dtype=np.float64)
    day = (pos["t_ms"] // 86_400_000).to_numpy()
    if len(np.unique(day)) < 2:
        return pd.Series(dtype=np.float64)
    cell = (np.floor(pos["x_m"] / cell_m).astype(np.int64) * 1_000_003
            + np.floor(pos["y_m"] / cell_m).astype(np.int64)).to_numpy()
    scans = pd.Series(pos["scan_id"].to_numpy()).groupby([day, cell]).nunique()
    good = scans[scans >= min_scans]
    means = pos.groupby([pos["ap"].to_numpy(), day, cell])["rssi_dbm"].mean()
    days = np.unique(good.index.get_level_values(0))
    out: dict[str, float] = {}
    for i, da in enumerate(days):
        for db in days[i + 1:]:
            common = np.intersect1d(good.loc[da].index.to_numpy(), good.loc[db].index.to_numpy())
            if len(common) < min_cells:
                continue
            lv = means.index
            part = means[lv.get_level_values(1).isin([da, db])
                         & lv.get_level_values(2).isin(common)]
            wide = part.unstack(level=1)
            if da not in wide or db not in wide:
                continue
            a, b = wide[da].fillna(-100.0), wide[db].fillna(-100.0)
            diff = (a - b).abs()[np.maximum(a, b) >= strong_dbm]
            stat = diff.groupby(level=0).agg(["median", "size"])
            for ap, v in stat[stat["size"] >= min_cells]["median"].items():
                out[ap] = max(out.get(ap, 0.0), float(v))
    return pd.Series(out, dtype=np.float64)


def _flatness(obs: pd.DataFrame, cell_m: float) -> pd.DataFrame:
    """Per AP: share of cells (``cell_m``) where it is heard and the SD (dB) of its cell means."""
    pos = obs[np.isfinite(obs["x_m"]) & np.isfinite(obs["y_m"])]
    if len(pos) == 0:
        return pd.DataFrame(columns=["coverage", "std_db"], dtype=np.float64)
    cell = (np.floor(pos["x_m"] / cell_m).astype(np.int64) * 1_000_003
            + np.floor(pos["y_m"] / cell_m).astype(np.int64))
    n_cells = cell.nunique()
    means = pos.groupby([pos["ap"], cell])["rssi_dbm"].mean()
    g = means.groupby(level=0)
    return pd.DataFrame({"coverage": g.size() / n_cells, "std_db": g.std(ddof=0)})


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
    info = pd.DataFrame(index=pd.Index(aps, name="ap"))
    info["n_scans"] = obs.groupby("ap")["scan_id"].nunique()
    info["n_walks"] = obs.groupby("ap")["trace_id"].nunique()
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
        fl = _flatness(part, p.flat_cell_m).reindex(info.index)
        flag((fl["coverage"] >= p.flat_coverage) & (fl["std_db"] <= p.flat_std_db), "flat",
             lambda a, fl=fl, where=where: f"coverage {fl.at[a, 'coverage']:.2f}, "
                                           f"SD {fl.at[a, 'std_db']:.1f} dB{where}")
        spread = _peak_spread(part, p.moving_strong_dbm, p.moving_min_walks).reindex(info.index)
        change = _survey_change(part, p.flat_cell_m, p.moving_strong_dbm,
                                p.moving_min_cells, p.moved_min_scans).reindex(info.index)
        flag(spread > p.moving_spread_m, "moving",
             lambda a, s=spread, where=where: f"walk peaks {s.at[a]:.0f} m apart{where}")
        flag(change > p.moved_change_db, "moved",
             lambda a, c=change, where=where: f"RSSI changed {c.at[a]:.0f} dB between "
                                              f"surveys{where}")
    if floor_column is not None:
        order = (list(floor_order) if floor_order is not None
                 else distinct_text(obs[floor_column]).tolist())
        rank = {f: i for i, f in enumerate(order)}
        strong = obs[obs["rssi_dbm"] >= p.far_floor_strong_dbm]
        idx = strong[floor_column].astype(str).map(rank)
        span = idx.groupby(strong["ap"]).agg(["min", "max"])
        gap = (span["max"] - span["min"]).reindex(info.index)
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
