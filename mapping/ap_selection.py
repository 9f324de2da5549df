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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from .errors import FingerprintError
from .radio_reduce import IntCodes, KeyedAggregate, TextCodes, walk_rows
from .radio_scans import OBS_COLUMNS

__all__ = [
    "HOTSPOT_SSID",
    "APEvidence",
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

    def summary_text(self) -> str:
        """:meth:`summary` as text, e.g. ``hotspot_ssid 70, moved 17, rare 218; 22 for more
        than one reason`` (the counts then add up to more than the dropped); '' if none."""
        text = ", ".join(f"{k} {v}" for k, v in self.summary().items())
        several = sum(";" in r for r in self.dropped["reason"])  # not .str: empty is float
        return text + (f"; {several} for more than one reason" if several else "")


def is_locally_administered(mac: Sequence[str] | NDArray[np.str_]) -> NDArray[np.bool_]:
    """True where the MAC address has the locally-administered bit (0x02 of the first octet)."""
    first = np.array([int(m[:2], 16) if len(m) >= 2 and re.fullmatch(r"[0-9a-fA-F]{2}", m[:2])
                      else 0 for m in np.asarray(mac).astype(str)], dtype=np.int64)
    return (first & 0x02) != 0


def _cell_keys(x_m: NDArray[np.float64], y_m: NDArray[np.float64],
               cell_m: float) -> NDArray[np.int64]:
    """Square cell (``cell_m``) of every point as one integer key."""
    return (np.floor(x_m / cell_m).astype(np.int64) * 1_000_003
            + np.floor(y_m / cell_m).astype(np.int64))


class APEvidence:
    """What :func:`select_aps` needs, reduced walk by walk.

    Per transmitter: scans and walks that heard it, floors where it was heard strongly; per
    floor, survey day (UTC) and 5 m cell (``flat_cell_m``): its RSSI sum and count (``flat``
    and ``moved``), and per walk the position of its strongest reading (``moving``). Memory
    grows with transmitters x cells x days and transmitters x walks, never with the rows.

    Add every walk once, whole (all its scans), with :meth:`add_walk`; then :meth:`select`.
    ``compact_rows``: partial sums held before they are merged.
    """

    _BITS: ClassVar[dict[str, int]] = {"floor": 7, "ap": 22, "day": 10, "cell": 24}  # one int64

    def __init__(self, params: APSelectionParams = APSelectionParams(), *,
                 compact_rows: int = 1_000_000) -> None:
        self.params = params
        self.aps = TextCodes()
        self.floors = TextCodes()
        self.days = IntCodes()
        self.cells = IntCodes()
        self.by_floor: bool | None = None
        def sums(*names: str) -> KeyedAggregate:
            return KeyedAggregate(names, compact_rows=compact_rows)

        self._per_ap = sums("n_scans", "n_walks")
        self._strong = sums("n")  # key (floor, ap)
        self._day_cell = sums("n")  # scans per (floor, day, cell)
        self._change = sums("s", "n")  # RSSI sum and count per (floor, ap, day, cell)
        self._peaks: dict[str, list[NDArray]] = {c: [] for c in ("floor", "ap", "rssi", "x_m",
                                                                  "y_m")}

    def _key(self, **codes: NDArray[np.int64] | int) -> NDArray[np.int64]:
        """One int64 key of the given codes (in the order floor, ap, day, cell)."""
        key = np.zeros(1, dtype=np.int64)
        for name, bits in self._BITS.items():
            key = (key << bits) | np.asarray(codes.get(name, 0), dtype=np.int64)
        return key

    def _part(self, key: NDArray[np.int64], name: str) -> NDArray[np.int64]:
        """The code ``name`` of packed keys."""
        shift = 0
        for n, bits in reversed(self._BITS.items()):
            if n == name:
                return (key >> shift) & ((1 << bits) - 1)
            shift += bits
        raise KeyError(name)

    def _check_sizes(self) -> None:
        for name, codes in (("floor", self.floors), ("ap", self.aps), ("day", self.days),
                            ("cell", self.cells)):
            if len(codes) > 1 << self._BITS[name]:
                raise FingerprintError(f"AP selection: more than {1 << self._BITS[name]} "
                                       f"distinct {name} values")

    def add_walk(self, obs: pd.DataFrame, *, floor_column: str | None = None) -> None:
        """Add the observation rows of one walk (:mod:`mapping.radio_scans`)."""
        missing = [c for c in OBS_COLUMNS if c not in obs.columns]
        if missing:
            raise FingerprintError(f"observation table lacks columns {missing}")
        if floor_column is not None and floor_column not in obs.columns:
            raise FingerprintError(f"observation table has no floor column {floor_column!r}")
        if self.by_floor is None:
            self.by_floor = floor_column is not None
        elif self.by_floor != (floor_column is not None):
            raise FingerprintError("add every walk with the same floor_column")
        if len(obs) == 0:
            return
        ap = self.aps.codes(obs["ap"])
        if (ap < 0).any():  # rows without a transmitter id say nothing
            obs, ap = obs[ap >= 0], ap[ap >= 0]
            if len(obs) == 0:
                return
        _, scan = np.unique(obs["scan_id"].to_numpy(np.int64), return_inverse=True)
        scan = scan.reshape(-1)
        pairs = np.unique(ap * (scan.max() + 1) + scan)  # distinct (AP, scan)
        heard, n_scans = np.unique(pairs // (scan.max() + 1), return_counts=True)
        self._per_ap.add(heard, n_scans=n_scans, n_walks=1)
        floor = (np.zeros(len(obs), dtype=np.int64) if floor_column is None
                 else self.floors.codes(obs[floor_column]))
        if floor_column is None and not len(self.floors):
            self.floors.codes(np.array([""]))
        self._check_sizes()
        if (floor < 0).any():  # rows without a floor: no floor rule sees them
            obs, ap, floor = obs[floor >= 0], ap[floor >= 0], floor[floor >= 0]
        p = self.params
        rssi = obs["rssi_dbm"].to_numpy(np.float64)
        with np.errstate(invalid="ignore"):
            strong = rssi >= p.far_floor_strong_dbm
        self._strong.add(np.unique(self._key(floor=floor[strong], ap=ap[strong])), n=1)
        x, y = obs["x_m"].to_numpy(np.float64), obs["y_m"].to_numpy(np.float64)
        ok = np.isfinite(x) & np.isfinite(y)
        if not ok.any():
            return
        floor, ap, rssi, x, y, scan = floor[ok], ap[ok], rssi[ok], x[ok], y[ok], scan[ok]
        cell = self.cells.codes(_cell_keys(x, y, p.flat_cell_m))
        day = self.days.codes(obs["t_ms"].to_numpy(np.int64)[ok] // 86_400_000)
        self._check_sizes()
        places, place = np.unique(self._key(floor=floor, day=day, cell=cell),
                                  return_inverse=True)
        n_scan = scan.max() + 1
        place_scans = np.unique(place.reshape(-1) * n_scan + scan)  # distinct (place, scan)
        counts = np.bincount(place_scans // n_scan, minlength=len(places))
        self._day_cell.add(places, n=counts)
        valid = np.isfinite(rssi)
        if not valid.any():
            return
        keys, inv = np.unique(self._key(floor=floor[valid], ap=ap[valid], day=day[valid],
                                        cell=cell[valid]), return_inverse=True)
        inv = inv.reshape(-1)
        self._change.add(keys, s=np.bincount(inv, weights=rssi[valid], minlength=len(keys)),
                         n=np.bincount(inv, minlength=len(keys)))
        # the first of each (floor, transmitter)'s strongest readings in this walk
        fa = self._key(floor=floor[valid], ap=ap[valid])
        order = np.lexsort((np.arange(len(fa)), -rssi[valid], fa))
        first = order[np.r_[True, fa[order][1:] != fa[order][:-1]]]
        for name, values in (("floor", floor[valid]), ("ap", ap[valid]), ("rssi", rssi[valid]),
                             ("x_m", x[valid]), ("y_m", y[valid])):
            self._peaks[name].append(values[first])

    def select(self, *, ssid: Mapping[str, str] | pd.Series | None = None,
               floor_order: Sequence[str] | None = None) -> APSelection:
        """The selection over every walk added (see :func:`select_aps` for the arguments)."""
        p = self.params
        names = self.aps.names()
        rank = self.aps.sorted_rank()
        aps = np.empty(len(names), dtype=names.dtype)
        aps[rank] = names

        def by_name(frame: pd.DataFrame, column: str) -> pd.Series:
            """Values of ``column`` per transmitter (index: AP code -> name)."""
            return pd.Series(frame[column].to_numpy(), index=aps[rank[frame.index.to_numpy()]])

        info = pd.DataFrame(index=pd.Index(aps, name="ap"))
        ap_codes, per_ap = self._per_ap.result()
        per_ap = pd.DataFrame(per_ap, index=ap_codes)
        for col in ("n_scans", "n_walks"):
            info[col] = by_name(per_ap, col).reindex(info.index).fillna(0).astype(np.int64)
        ssid_s = pd.Series(ssid, dtype=object) if ssid is not None else pd.Series(dtype=object)
        info["ssid"] = ssid_s.reindex(info.index).fillna("").astype(str)
        info["locally_administered"] = is_locally_administered(aps)
        reasons: dict[str, list[str]] = {a: [] for a in aps}
        details: dict[str, list[str]] = {a: [] for a in aps}

        def flag(mask: pd.Series, reason: str, text: Callable[[str], str]) -> None:
            for a in mask[mask].index:
                reasons[a].append(reason)
                details[a].append(text(a))

        flag((info["n_scans"] < p.min_scans) | (info["n_walks"] < p.min_walks), "rare",
             lambda a: f"{info.at[a, 'n_scans']} scans/{info.at[a, 'n_walks']} walks")
        if ssid is not None:
            flag(info["ssid"].map(lambda s: bool(HOTSPOT_SSID.search(s))), "hotspot_ssid",
                 lambda a: f"ssid {info.at[a, 'ssid']!r}")
        if p.drop_locally_administered:
            flag(info["locally_administered"], "locally_administered", lambda a: "LAA bit")

        floor_names = self.floors.names()
        change_keys, change = self._change.result()
        place_keys, place = self._day_cell.result()
        change_floor, place_floor = (self._part(k, "floor") for k in (change_keys, place_keys))
        day_of = self.days.values()  # UTC day number per day code
        peaks = pd.DataFrame({n: np.concatenate(v) if v else np.zeros(0)
                              for n, v in self._peaks.items()})
        for f in np.argsort(floor_names, kind="stable"):
            where = f" on {floor_names[f]}" if self.by_floor else ""
            on_f = change_floor == f
            ch = pd.DataFrame({c: self._part(change_keys[on_f], c) for c in ("ap", "cell")})
            ch["day"] = day_of[self._part(change_keys[on_f], "day")]
            ch["mean"] = change["s"][on_f] / change["n"][on_f]
            ch["s"], ch["n"] = change["s"][on_f], change["n"][on_f]
            pl = pd.DataFrame({"day": day_of[self._part(place_keys[place_floor == f], "day")],
                               "cell": self._part(place_keys[place_floor == f], "cell"),
                               "n": place["n"][place_floor == f]})
            fl = _flatness(pl["cell"].nunique(), ch)
            fl = pd.DataFrame({c: by_name(fl, c) for c in fl.columns}).reindex(info.index)
            flag((fl["coverage"] >= p.flat_coverage) & (fl["std_db"] <= p.flat_std_db), "flat",
                 lambda a, fl=fl, where=where: f"coverage {fl.at[a, 'coverage']:.2f}, "
                                               f"SD {fl.at[a, 'std_db']:.1f} dB{where}")
            spread = _peak_spread(peaks[peaks["floor"].to_numpy() == f], p.moving_strong_dbm,
                                  p.moving_min_walks)
            spread = by_name(spread.to_frame("v"), "v").reindex(info.index)
            change_db = _survey_change(pl, ch, p.moving_strong_dbm, p.moving_min_cells,
                                       p.moved_min_scans)
            change_db = by_name(change_db.to_frame("v"), "v").reindex(info.index)
            flag(spread > p.moving_spread_m, "moving",
                 lambda a, s=spread, where=where: f"walk peaks {s.at[a]:.0f} m apart{where}")
            flag(change_db > p.moved_change_db, "moved",
                 lambda a, c=change_db, where=where: f"RSSI changed {c.at[a]:.0f} dB between "
                                                     f"surveys{where}")
        if self.by_floor:
            order = (list(floor_order) if floor_order is not None
                     else np.sort(floor_names).tolist())
            level_of = {str(f): i for i, f in enumerate(order)}  # a repeated name: last place
            strong, _ = self._strong.result()
            level = np.array([level_of.get(str(n), -1) for n in floor_names],
                             dtype=np.int64)[self._part(strong, "floor")]
            known = level >= 0  # floors not in floor_order do not count
            span = pd.Series(level[known]).groupby(self._part(strong, "ap")[known]).agg(
                ["min", "max"])
            gap = by_name((span["max"] - span["min"]).astype(np.float64).to_frame("v"),
                          "v").reindex(info.index)
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


def _flatness(n_cells: int, change: pd.DataFrame) -> pd.DataFrame:
    """Per AP code: share of the floor's ``n_cells`` cells where it is heard and the SD (dB)
    of its cell means (``change``: RSSI sum ``s`` and count ``n`` per (AP, day, cell))."""
    if len(change) == 0:
        return pd.DataFrame({"coverage": [], "std_db": []}, dtype=np.float64)
    per_cell = change.groupby(["ap", "cell"], sort=False)[["s", "n"]].sum()
    means = (per_cell["s"] / per_cell["n"]).groupby(level="ap")
    return pd.DataFrame({"coverage": means.size() / n_cells, "std_db": means.std(ddof=0)})


def _peak_spread(peaks: pd.DataFrame, strong_dbm: float, min_walks: int) -> pd.Series:
    """Per AP code: median distance (m) of the per-walk strongest positions (``peaks``: one
    row per (AP, walk)) from their median point, over walks whose strongest reading is at least
    ``strong_dbm`` (APs with fewer such walks are left out)."""
    peaks = peaks[peaks["rssi"].to_numpy(np.float64) >= strong_dbm]
    peaks = peaks[peaks.groupby("ap")["ap"].transform("size").to_numpy() >= min_walks]
    if len(peaks) == 0:
        return pd.Series(dtype=np.float64)
    xy = peaks[["x_m", "y_m"]].astype(np.float64)
    ap = peaks["ap"].to_numpy()
    centre = xy.groupby(ap).transform("median")
    dist = pd.Series(np.hypot(xy["x_m"] - centre["x_m"], xy["y_m"] - centre["y_m"]).to_numpy())
    return dist.groupby(ap).median()


def _survey_change(day_cell: pd.DataFrame, change: pd.DataFrame, strong_dbm: float,
                   min_cells: int, min_scans: int) -> pd.Series:
    """Per AP code: median |RSSI difference| (dB) between two surveys (UTC days) over the cells
    where both surveys have at least ``min_scans`` scans and either heard it at least
    ``strong_dbm`` ("not heard in any of those scans" = -100 dBm; left out with fewer than
    ``min_cells`` such cells). A moved AP is loud where it used to be silent.

    ``day_cell``: scans ``n`` per (day, cell); ``change``: mean RSSI ``mean`` per (AP, day,
    cell)."""
    days = np.unique(day_cell["day"].to_numpy())
    if len(days) < 2:
        return pd.Series(dtype=np.float64)
    enough = day_cell[day_cell["n"].to_numpy() >= min_scans]
    good = {d: np.sort(enough["cell"].to_numpy()[enough["day"].to_numpy() == d]) for d in days}
    mean = change[["ap", "cell", "day", "mean"]]
    out: dict[int, float] = {}
    for i, da in enumerate(days):
        for db in days[i + 1:]:
            common = np.intersect1d(good[da], good[db], assume_unique=True)
            if len(common) < min_cells:
                continue
            sides = [mean[(mean["day"].to_numpy() == d) & np.isin(mean["cell"].to_numpy(), common)]
                     .set_index(["ap", "cell"])["mean"] for d in (da, db)]
            if not len(sides[0]) or not len(sides[1]):
                continue
            both = pd.concat(sides, axis=1, keys=["a", "b"]).fillna(-100.0)
            both = both[np.maximum(both["a"], both["b"]) >= strong_dbm]
            diff = (both["a"] - both["b"]).abs()
            stat = diff.groupby(level="ap").agg(["median", "size"])
            for ap, v in stat[stat["size"] >= min_cells]["median"].items():
                out[int(ap)] = max(out.get(int(ap), 0.0), float(v))
    return pd.Series(out, dtype=np.float64)


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
    evidence = APEvidence(params)
    if len(obs) == 0:
        evidence.add_walk(obs, floor_column=floor_column)  # checks the columns
    for rows in walk_rows(obs):
        evidence.add_walk(obs.iloc[rows], floor_column=floor_column)
    return evidence.select(ssid=ssid, floor_order=floor_order)

