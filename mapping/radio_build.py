"""The radio part of a site's bundles: device table, AP selection, fingerprints, floor model.

One pass over the processed Wi-Fi and BLE rows of every floor of a site:

1. **Device table** (:func:`mapping.device_calibration.calibrate_devices`, Wi-Fi rows of all
   floors): ``k, b`` per phone model against the model with the most scans. Every walk's RSSI
   is mapped onto that reference scale before anything else.
2. **AP selection** per kind over all floors (:func:`mapping.ap_selection.select_aps`): the
   dropped transmitters and their reasons go into the site bundle's ``<kind>_dropped`` table.
3. **Fingerprints** per floor and kind (:func:`mapping.fingerprints.build_fingerprints`, default
   1 m reference points, stale Wi-Fi rows dropped): the floor bundle's ``<kind>_rp``,
   ``<kind>_fp`` and ``<kind>_meta`` tables, read by
   :class:`localize.fingerprint_positioner.FingerprintPositioner`.
4. **Floor model** (:func:`mapping.floor_model.fit_floor_model`, Wi-Fi, or BLE for a site
   without Wi-Fi) with its walk-grouped cross-validated accuracy: the site bundle's
   ``floor_coef``, ``floor_intercept`` and ``floor_meta`` tables, read by
   :class:`localize.floor_classifier.FloorClassifier`. Beside a Wi-Fi floor model, a **BLE
   floor model** (same fit, on the BLE windows the BLE fingerprints are built from) when BLE
   rows of kept transmitters are on at least two floors: ``ble_floor_coef``,
   ``ble_floor_intercept``, ``ble_floor_meta``, for walks without Wi-Fi (an iPhone logs BLE
   only) that name no floor. The Wi-Fi model reads levels, the BLE one presence
   (``RadioParams.wifi_floor_feature``, ``ble_floor_feature``): an unknown phone's Wi-Fi
   RSSI can be calibrated online against the fingerprints, a BLE window's few beacons cannot
   (docs/radio.md).

The rows are reduced walk by walk (bounded memory, ``docs/reliability.md``): AP selection
(:class:`~mapping.ap_selection.APEvidence`) and fingerprints
(:class:`~mapping.fingerprints.FingerprintSums`) keep per-key sums, never the rows. The device
fit and the floor model need rows: they use a deterministic sample of whole walks of at most
``calibration_max_rows`` rows per phone model and ``floor_model_max_rows`` rows per floor
(:func:`~mapping.radio_reduce.capped_walk_sample`; every walk when they fit, as on site1).

A floor without any row of a kind simply has no tables of that kind (reported in
``metrics["radio"]``); a site without any radio row has no radio tables at all.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import pandas as pd
import pyarrow as pa
from numpy.typing import NDArray

from localize.bundle import RSSI_RANGE_DBM
from survey.errors import ProcessingError
from survey.memory import release_free_memory
from survey.process_store import processed_part, processed_walks, walks_per_site
from survey.store import SurveyStore

from .ap_selection import APEvidence, APSelection, APSelectionParams
from .bundle_writer import BundleContent
from .device_calibration import DEVICE_TABLE_COLUMNS, calibrate_devices
from .errors import FingerprintError
from .fingerprints import DEFAULT_CELL_M, FingerprintDB, FingerprintSums
from .floor_model import FloorModel, fit_floor_model
from .radio_reduce import TextCodes, capped_walk_sample, walk_rows
from .radio_scans import OBS_COLUMNS, ble_observations, wifi_observations

__all__ = ["KINDS", "RadioParams", "SiteRadio", "WalkSource", "build_site_radio", "calibrated",
           "format_share", "reduce_site_radio", "site_observations", "site_radio", "store_walks",
           "table_walks"]

KINDS = ("wifi", "ble")


@dataclass(frozen=True)
class RadioParams:
    """Radio-map parameters (m, ms, rows)."""

    cell_m: float = DEFAULT_CELL_M
    ble_window_ms: int = 2000
    select_aps: bool = True
    ap_selection: APSelectionParams = field(default_factory=APSelectionParams)
    calibrate_devices: bool = True
    calibration_max_rows: int = 1_000_000
    floor_model: bool = True
    floor_cv_folds: int = 5
    floor_model_max_rows: int = 750_000
    #: What a transmitter in a scan gives each kind's floor model (``level``, ``presence``).
    wifi_floor_feature: str = "level"
    ble_floor_feature: str = "presence"
    seed: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


def _table(frame: pd.DataFrame) -> pa.Table:
    return pa.Table.from_pandas(frame.reset_index(drop=True), preserve_index=False)


WALK_COLUMNS = ("trace_id", "floor", "device_model", "rows_wifi", "rows_ble", "scans_wifi")


@dataclass(frozen=True)
class WalkSource:
    """Where the radio build reads its observation rows, walk by walk.

    Attributes
    ----------
    walks : DataFrame
        One row per walk in reading order, columns :data:`WALK_COLUMNS` (rows and Wi-Fi scans
        per walk may be estimates: they only size the samples and choose the reference phone).
    read : callable
        ``read(kind, walks)`` yields ``(walk, obs)`` for the rows of ``walks`` (a part of
        :attr:`walks`) that have rows of ``kind``: ``obs`` is the walk's observation table
        (:mod:`mapping.radio_scans`) with ``floor`` and ``ssid`` columns, scan ids unique over
        the source.
    """

    walks: pd.DataFrame
    read: Callable[[str, pd.DataFrame], Iterator[tuple[pd.Series, pd.DataFrame]]]


def store_walks(store: SurveyStore, site: str | None, floors: Sequence[str], *,
                ble_window_ms: int = 2000, exclude_walks: Collection[str] = ()) -> WalkSource:
    """The processed walks of ``floors`` in a survey store (all but ``exclude_walks``), read
    one at a time with their text columns as categoricals."""
    try:
        walks = processed_walks(store, site=site)
    except ProcessingError:  # never processed: no rows
        walks = pd.DataFrame(columns=["floor", "trace_id", "site"])
    walks = walks[~walks["trace_id"].isin(list(exclude_walks))]
    walks = pd.concat([walks.iloc[:0]] + [walks[walks["floor"] == f] for f in floors],
                      ignore_index=True)
    if site is None and walks["site"].nunique() > 1:  # one radio map of two buildings
        raise FingerprintError(f"{store.root}: floors {', '.join(floors)} have walks of "
                               f"several sites ({walks_per_site(walks)}); give the site")
    cat = store.traces(site).set_index("trace_id")
    counts = {"device_model": "device_model", "rows_wifi": "n_wifi_rows",
              "rows_ble": "n_ble_rows", "scans_wifi": "n_scans"}
    for col, name in counts.items():
        walks[col] = walks["trace_id"].map(cat[name]).to_numpy()
    walks["device_model"] = walks["device_model"].fillna("").astype(str)
    table = walks[list(WALK_COLUMNS)].copy()
    offset = [0]  # scan ids unique over everything read from this source

    def read(kind: str, chosen: pd.DataFrame) -> Iterator[tuple[pd.Series, pd.DataFrame]]:
        for _, r in walks[walks["trace_id"].isin(chosen["trace_id"])].iterrows():
            rows = processed_part(store, kind, r, text_as_category=True)
            if len(rows) == 0:
                continue
            rows.insert(0, "trace_id", r["trace_id"])
            if kind == "wifi":
                obs = wifi_observations(rows, invalid="drop")
                first = rows.drop_duplicates("bssid")  # an AP's SSID: that of its first row
                ssid = pd.Series(first["ssid"].astype(str).to_numpy(),
                                 index=first["bssid"].astype(str).str.lower().to_numpy())
                obs["ssid"] = obs["ap"].map(ssid[~ssid.index.duplicated()]).fillna("")
            else:
                obs = ble_observations(rows, window_ms=ble_window_ms, invalid="drop")
                obs["ssid"] = ""
            del rows
            if len(obs) == 0:
                continue
            obs["scan_id"] += offset[0]
            offset[0] = int(obs["scan_id"].max()) + 1
            obs["floor"] = r["floor"]
            yield r[list(WALK_COLUMNS)], obs

    return WalkSource(table, read)


def table_walks(obs: Mapping[str, pd.DataFrame], device_of: Mapping[str, str] | pd.Series,
                floors: Sequence[str]) -> WalkSource:
    """The walks of observation tables in memory (kind -> table with ``floor`` and, for
    Wi-Fi, ``ssid`` columns; :func:`site_observations`)."""
    floors = [str(f) for f in floors]
    device = pd.Series(device_of, dtype=object)
    rows_of: dict[str, dict[str, NDArray[np.intp]]] = {}
    parts = []
    for kind in KINDS:
        o = obs.get(kind)
        if o is None or len(o) == 0:
            rows_of[kind] = {}
            continue
        groups = walk_rows(o)
        trace = o["trace_id"].to_numpy()
        rows_of[kind] = {str(trace[g[0]]): g for g in groups}
        scans = [len(np.unique(o["scan_id"].to_numpy()[g])) for g in groups]
        parts.append(pd.DataFrame({"trace_id": [str(trace[g[0]]) for g in groups],
                                   "floor": [str(o["floor"].iloc[g[0]]) for g in groups],
                                   f"rows_{kind}": [len(g) for g in groups],
                                   f"scans_{kind}": scans}))
    walks = pd.DataFrame(columns=["trace_id", "floor"])
    for part in parts:
        walks = walks.merge(part, on=["trace_id", "floor"], how="outer", sort=False)
    walks = pd.concat([walks.iloc[:0]] + [walks[walks["floor"] == f] for f in floors],
                      ignore_index=True)
    for col in ("rows_wifi", "rows_ble", "scans_wifi"):
        walks[col] = walks[col].fillna(0).astype(np.int64) if col in walks else 0
    walks["device_model"] = walks["trace_id"].map(device).to_numpy()
    table = walks[list(WALK_COLUMNS)]

    def read(kind: str, chosen: pd.DataFrame) -> Iterator[tuple[pd.Series, pd.DataFrame]]:
        o = obs.get(kind)
        for _, w in chosen.iterrows():
            rows = rows_of[kind].get(w["trace_id"])
            if rows is not None:
                part = o.iloc[rows]
                yield w, part if "ssid" in part else part.assign(ssid="")

    return WalkSource(table, read)


def first_ssids(obs: pd.DataFrame, ssid_of: dict[str, str]) -> None:
    """Record the SSID of each AP of ``obs`` not yet in ``ssid_of`` (its first row's)."""
    code, aps = pd.factorize(obs["ap"])
    _, first = np.unique(code, return_index=True)  # codes number APs by first appearance
    first = first[code[first] >= 0]  # not the missing ids
    ssids = obs["ssid"].to_numpy()[first]
    for ap, ssid in zip(aps, ssids):
        ssid_of.setdefault(str(ap), str(ssid))


def site_observations(store: SurveyStore, site: str | None, floors: Sequence[str], kind: str,
                      *, ble_window_ms: int = 2000,
                      exclude_walks: Collection[str] = ()) -> pd.DataFrame:
    """Observation table (:mod:`mapping.radio_scans`) of ``kind`` over ``floors`` with a
    ``floor`` column and an ``ssid`` column (Wi-Fi; "" for BLE); rows of any age.
    RSSI outside the phone range is dropped (counted by the reader's checks upstream).
    Walks whose trace id is in ``exclude_walks`` are left out.

    The whole table in memory (for evaluation; the build itself reduces walk by walk), with
    the text columns (``trace_id``, ``ap``, ``ssid``, ``floor``) as categoricals: about 60
    bytes per observation row."""
    source = store_walks(store, site, floors, ble_window_ms=ble_window_ms,
                         exclude_walks=exclude_walks)
    columns = (*OBS_COLUMNS, "floor")
    parts: dict[str, list[np.ndarray]] = {c: [] for c in columns}  # per column, per walk
    codes = {c: TextCodes() for c in ("trace_id", "ap", "floor")}
    ssid_of: dict[str, str] = {}
    for _, obs in source.read(kind, source.walks):
        for col in columns:
            parts[col].append(codes[col].codes(obs[col]).astype(np.int32) if col in codes
                              else obs[col].to_numpy())
        first_ssids(obs, ssid_of)
    if not parts["scan_id"]:
        return pd.DataFrame(columns=[*OBS_COLUMNS, "ssid", "floor"])
    # One column at a time, each column's walk pieces freed as soon as it is joined: the peak
    # is the table plus one column, not twice the table.
    data = {}
    for col in columns:
        joined = np.concatenate(parts.pop(col))
        data[col] = (pd.Categorical.from_codes(joined, codes[col].names()) if col in codes
                     else joined)
    # SSID of each row's AP (the first seen), coded through the AP's code
    ssid_code, ssids = pd.factorize(np.array([ssid_of.get(ap, "") for ap in codes["ap"].names()],
                                             dtype=object))
    data["ssid"] = pd.Categorical.from_codes(ssid_code[data["ap"].codes], ssids)
    data["floor"] = data.pop("floor")
    table = pd.DataFrame(data, copy=False)
    release_free_memory()  # the walks' freed buffers
    return table


@dataclass
class SiteRadio:
    """Everything radio of a site (see the module docstring).

    Attributes
    ----------
    devices : DataFrame
        Device table (columns :data:`mapping.device_calibration.DEVICE_TABLE_COLUMNS`).
    selections : dict
        Kind -> :class:`~mapping.ap_selection.APSelection`.
    fingerprints : dict
        ``(floor, kind)`` -> :class:`~mapping.fingerprints.FingerprintDB`.
    floor_model : FloorModel or None
    floor_model_kind : str
        ``wifi``, or ``ble`` for a site without Wi-Fi ("" without a floor model).
    notes : list of str
        What was missing (floors without Wi-Fi, ...), for the build log and the manifest.
    ble_floor_model : FloorModel or None
        The BLE floor model beside a Wi-Fi one (None when ``floor_model`` is BLE already, or
        BLE is on fewer than two floors).
    """

    floors: list[str]
    devices: pd.DataFrame
    selections: dict[str, APSelection]
    fingerprints: dict[tuple[str, str], FingerprintDB]
    floor_model: FloorModel | None
    floor_model_kind: str
    params: RadioParams
    notes: list[str] = field(default_factory=list)
    ble_floor_model: FloorModel | None = None
    #: ``(floor, kind)`` -> reference points :meth:`on_plan` left out.
    off_plan: dict[tuple[str, str], int] = field(default_factory=dict)

    def on_plan(self, floor: str,
                reachable: Callable[[NDArray[np.float64], NDArray[np.float64]],
                                    NDArray[np.bool_]]) -> SiteRadio:
        """A copy whose ``floor`` fingerprints keep only the reference points where
        ``reachable(x_m, y_m)`` (shape (R,) each) is true: a fingerprint where the floor plan
        says nobody can stand would pull a Wi-Fi/BLE fix off the map. The number left out per
        kind is in :attr:`off_plan` and :meth:`floor_metrics`."""
        fingerprints, off_plan = dict(self.fingerprints), dict(self.off_plan)
        for kind in KINDS:
            db = fingerprints.get((floor, kind))
            if db is None:
                continue
            keep = reachable(db.rp["x_m"].to_numpy(np.float64), db.rp["y_m"].to_numpy(np.float64))
            fingerprints[floor, kind] = db.at_points(keep)
            off_plan[floor, kind] = int((~keep).sum())
        return replace(self, fingerprints=fingerprints, off_plan=off_plan)

    def floor_tables(self, floor: str) -> dict[str, pa.Table]:
        """Tables for the floor bundle: ``<kind>_rp``, ``<kind>_fp``, ``<kind>_meta`` and
        ``devices``."""
        tables = {"devices": _table(self.devices)}
        for kind in KINDS:
            db = self.fingerprints.get((floor, kind))
            if db is None:
                continue
            for name, frame in db.to_tables().items():
                tables[f"{kind}_{name}"] = _table(frame)
        return tables

    def floor_metrics(self, floor: str) -> dict:
        """Per-floor radio summary for the manifest's metrics."""
        out: dict = {}
        for kind in KINDS:
            db = self.fingerprints.get((floor, kind))
            out[kind] = (None if db is None else
                         {"reference_points": len(db), "transmitters": int(len(db.aps)),
                          "scans": int(db.rp["n_scans"].sum()), "cell_m": db.cell_m,
                          "off_plan_reference_points": self.off_plan.get((floor, kind), 0)})
        return out

    def site_content(self, site_id: str, *, build: dict | None = None) -> BundleContent:
        """The site bundle (kind ``site``): floor model, device table, AP selection report."""
        tables: dict[str, pa.Table] = {"devices": _table(self.devices)}
        metrics: dict = {"floors": list(self.floors), "notes": list(self.notes),
                         "floor_model": None}
        for kind, sel in self.selections.items():
            tables[f"{kind}_dropped"] = _table(sel.dropped)
            metrics[f"{kind}_ap_selection"] = {"kept": int(len(sel.kept)),
                                               "dropped": int(len(sel.dropped)),
                                               "reasons": sel.summary()}
        metrics["ble_floor_model"] = None
        for prefix, key, model, kind in (
                ("", "floor_model", self.floor_model, self.floor_model_kind),
                ("ble_", "ble_floor_model", self.ble_floor_model, "ble")):
            if model is None:
                continue
            t = model.to_tables()
            for name in ("coef", "intercept", "meta"):
                tables[f"{prefix}floor_{name}"] = _table(t[name])
            metrics[key] = _floor_model_metrics(model, kind)
        return BundleContent(site_id=site_id, floor_id="", floor_name="", kind="site",
                             tables=tables, build={**(build or {}),
                                                   "radio_params": self.params.to_dict()},
                             metrics=metrics)


def _floor_model_metrics(model: FloorModel, kind: str) -> dict:
    """A floor model's summary for the site manifest's metrics."""
    m = model.meta
    return {"kind": kind, "feature": model.feature, "floors": model.floors.tolist(),
            "transmitters": int(len(model.aps)),
            "cv_folds": int(m.get("cv_folds", 0)),
            **{k: (None if not np.isfinite(m.get(k, np.nan)) else float(m[k]))
               for k in ("cv_scan_accuracy", "cv_sequence_accuracy", "cv_walk_accuracy")}}


def calibrated(obs: pd.DataFrame, device_of: pd.Series, devices: pd.DataFrame) -> pd.DataFrame:
    """``obs`` with every walk's RSSI mapped through its phone model's ``k, b`` (dBm); models
    not in the device table are left as they are."""
    traces = pd.Series(pd.unique(obs["trace_id"]))
    walks = pd.DataFrame({"trace_id": traces, "device_model": traces.map(device_of)})
    return _with_calibration(obs, _calibration_of(walks, devices))


def _with_calibration(obs: pd.DataFrame, kb_of: Mapping[str, tuple[float, float]]
                      ) -> pd.DataFrame:
    """``obs`` with the RSSI of each walk in ``kb_of`` (trace id -> ``(k, b)``) mapped to
    ``k * rssi + b`` (dBm), kept within :data:`~localize.bundle.RSSI_RANGE_DBM` (what a
    phone reports, and what a bundle's fingerprints may hold: a 0 dBm reading of a phone with
    ``b > 0`` is 0 dBm on the reference phone's scale, not above); other columns shared."""
    traces = pd.Index(np.asarray(pd.unique(obs["trace_id"]), dtype=object).astype(str))
    if not any(t in kb_of for t in traces):
        return obs
    kb = np.array([kb_of.get(t, (1.0, 0.0)) for t in traces], dtype=np.float64)
    idx = traces.get_indexer(np.asarray(obs["trace_id"], dtype=object).astype(str))
    return obs.assign(rssi_dbm=np.clip(kb[idx, 0] * obs["rssi_dbm"].to_numpy() + kb[idx, 1],
                                       *RSSI_RANGE_DBM))


def format_share(v: float | None) -> str:
    """A cross-validated accuracy for the log: a percentage, or n/a (one floor, no folds)."""
    return "n/a" if v is None or not np.isfinite(v) else f"{100 * v:.2f} %"


def n_floors_text(n: int) -> str:
    """``"1 floor"``, ``"3 floors"``."""
    return f"{n} floor" + ("" if n == 1 else "s")


def build_site_radio(store: SurveyStore | str, floors: Sequence[str], *,
                     site: str | None = None, params: RadioParams = RadioParams(),
                     exclude_walks: Collection[str] = (),
                     progress: Callable[[str], None] | None = None) -> SiteRadio:
    """Device table, AP selection, fingerprints and floor model of a site's floors, from all
    their processed walks but ``exclude_walks`` (trace ids), read walk by walk."""
    store = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
    floors = [str(f) for f in floors]
    device_of = store.traces(site).set_index("trace_id")["device_model"].fillna("").astype(str)
    source = store_walks(store, site, floors, ble_window_ms=params.ble_window_ms,
                         exclude_walks=exclude_walks)
    radio = reduce_site_radio(source, device_of, floors, params=params, progress=progress)
    release_free_memory()  # the floor model's rows and fit
    return radio


def site_radio(obs: dict[str, pd.DataFrame], device_of: pd.Series, floors: Sequence[str], *,
               params: RadioParams = RadioParams(),
               progress: Callable[[str], None] | None = None) -> SiteRadio:
    """:func:`build_site_radio` on observation tables in memory (pure computation).

    Parameters
    ----------
    obs : dict
        Kind (``wifi``, ``ble``) -> observation table over the site's floors with ``floor``
        and ``ssid`` columns (:func:`site_observations`), rows of any age.
    device_of : Series
        Phone model per trace id.
    floors : sequence of str
        Floors bottom to top.
    """
    return reduce_site_radio(table_walks(obs, device_of, floors), device_of, floors,
                             params=params, progress=progress)


def _device_table(source: WalkSource, device_of: pd.Series, params: RadioParams,
                  say: Callable[[str], None]) -> pd.DataFrame:
    """The device table (empty without Wi-Fi); with several phone models, fitted on a capped
    sample of each model's walks."""
    walks = source.walks[source.walks["rows_wifi"] > 0]
    if not len(walks) or not params.calibrate_devices:
        return pd.DataFrame({c: [] for c in DEVICE_TABLE_COLUMNS})
    unknown = walks["trace_id"][walks["device_model"].isna()]
    if len(unknown):
        raise FingerprintError(f"no device model for traces {sorted(map(str, unknown))[:5]}")
    models = walks.assign(device_model=walks["device_model"].astype(str))
    scans = models.groupby("device_model", sort=True)["scans_wifi"].sum()
    reference = str(scans.sort_values(ascending=False, kind="stable").index[0])
    if len(scans) == 1:
        devices = pd.DataFrame([{c: v for c, v in zip(
            DEVICE_TABLE_COLUMNS, (reference, 1.0, 0.0, 0, 0.0, "reference"))}])
    else:
        sample: set[str] = set()
        for _, part in models.groupby("device_model", sort=True):
            sample |= capped_walk_sample(part.set_index("trace_id")["rows_wifi"],
                                         params.calibration_max_rows, seed=params.seed)
        parts = [o for _, o in source.read("wifi", walks[walks["trace_id"].isin(sample)])]
        if not parts:  # no valid row after all
            return pd.DataFrame({c: [] for c in DEVICE_TABLE_COLUMNS})
        devices = calibrate_devices(pd.concat(parts, ignore_index=True), device_of,
                                    reference_model=reference, floor_column="floor")
        del parts
    fitted = devices[devices["method"] == "offline"]
    say("devices: reference " + reference + "; "
        + (", ".join(f"{r.device_model} k={r.k:.3f} b={r.b:+.1f} dB"
                     for r in fitted.itertuples()) or "no other model fitted"))
    return devices


def _calibration_of(walks: pd.DataFrame, devices: pd.DataFrame) -> dict[str, tuple[float, float]]:
    """``(k, b)`` per trace id whose model's calibration is not the identity."""
    table = devices.set_index("device_model")
    kb = {str(m): (float(r["k"]), float(r["b"])) for m, r in table.iterrows()
          if (r["k"], r["b"]) != (1.0, 0.0)}
    return {str(t): kb[str(m)] for t, m in zip(walks["trace_id"], walks["device_model"])
            if str(m) in kb}


class _SampleRows:
    """Observation rows of the floor model's sample of walks, per floor, held compactly (text
    as integer codes, no positions: about 32 bytes per row)."""

    def __init__(self) -> None:
        self.aps, self.traces = TextCodes(), TextCodes()
        self.parts: dict[str, list[dict[str, NDArray]]] = {}

    def add(self, floor: str, obs: pd.DataFrame) -> None:
        self.parts.setdefault(floor, []).append({
            "scan_id": obs["scan_id"].to_numpy(np.int64), "t_ms": obs["t_ms"].to_numpy(np.int64),
            "rssi_dbm": obs["rssi_dbm"].to_numpy(np.float64),
            "ap": self.aps.codes(obs["ap"]).astype(np.int32),
            "trace_id": self.traces.codes(obs["trace_id"]).astype(np.int32)})

    def tables(self, floors: Sequence[str], kept: set[str] | None) -> dict[str, pd.DataFrame]:
        """Floor -> observation table (rows of transmitters in ``kept``; all when None),
        positions and ages NaN."""
        aps, traces = self.aps.names(), self.traces.names()
        keep = (np.ones(len(aps), dtype=bool) if kept is None
                else np.isin(aps, np.array(sorted(kept), dtype=str)))
        out = {}
        for floor in floors:
            parts = self.parts.pop(floor, [])
            if not parts:
                out[floor] = pd.DataFrame(columns=list(OBS_COLUMNS))
                continue
            cols = {c: np.concatenate([p[c] for p in parts]) for c in parts[0]}
            rows = keep[cols["ap"]]
            cols = {c: v[rows] for c, v in cols.items()}
            n = len(cols["ap"])
            out[floor] = pd.DataFrame({
                "trace_id": pd.Categorical.from_codes(cols["trace_id"], traces),
                "scan_id": cols["scan_id"], "t_ms": cols["t_ms"],
                "x_m": np.full(n, np.nan), "y_m": np.full(n, np.nan),
                "ap": pd.Categorical.from_codes(cols["ap"], aps),
                "rssi_dbm": cols["rssi_dbm"], "age_ms": np.full(n, np.nan)})
        return out


def reduce_site_radio(source: WalkSource, device_of: pd.Series, floors: Sequence[str], *,
                      params: RadioParams = RadioParams(),
                      progress: Callable[[str], None] | None = None) -> SiteRadio:
    """The site's radio maps from its walks, read one at a time (module docstring)."""
    say = progress or (lambda msg: None)
    floors = [str(f) for f in floors]
    notes: list[str] = []
    devices = _device_table(source, device_of, params, say)
    kb_of = _calibration_of(source.walks, devices)
    selections: dict[str, APSelection] = {}
    fingerprints: dict[tuple[str, str], FingerprintDB] = {}
    samples: dict[str, tuple[_SampleRows, set[str] | None]] = {}  # kind -> floor model rows
    for kind in KINDS:
        walks = source.walks[source.walks[f"rows_{kind}"] > 0]
        evidence = APEvidence(params.ap_selection)
        sums = {f: FingerprintSums(kind=kind, cell_m=params.cell_m) for f in floors}
        sample: set[str] = set()
        if params.floor_model:
            for _, part in walks.groupby("floor", sort=False):
                sample |= capped_walk_sample(part.set_index("trace_id")[f"rows_{kind}"],
                                             params.floor_model_max_rows, seed=params.seed)
        model_rows = _SampleRows()
        ssid_of: dict[str, str] = {}
        seen = set()
        n_read = 0
        for n_read, (walk, obs) in enumerate(source.read(kind, walks), 1):
            if n_read % 100 == 0:
                say(f"{kind}: read walk {n_read}/{len(walks)}")
            if kind == "wifi":
                obs = _with_calibration(obs, kb_of)
                first_ssids(obs, ssid_of)
            evidence.add_walk(obs, floor_column="floor")
            floor = obs["floor"].to_numpy()
            one = bool((floor == walk["floor"]).all())  # else a walk on several floors
            for f in ([walk["floor"]] if one else pd.unique(floor)):
                if f not in sums:  # a floor not asked for
                    continue
                part = obs if one else obs[floor == f]
                sums[f].add(part)
                seen.add(f)
                if walk["trace_id"] in sample:
                    model_rows.add(f, part)
        if n_read:  # the last progress line; a walk whose rows are all invalid is passed over
            say(f"{kind}: read {n_read} walks" + (f" ({len(walks) - n_read} without valid rows)"
                                                  if n_read < len(walks) else ""))
        if not seen:
            notes.append(f"no {kind} rows on any floor")
            continue
        kept = None
        if params.select_aps:
            sel = evidence.select(ssid=ssid_of if kind == "wifi" else None, floor_order=floors)
            selections[kind] = sel
            kept = set(sel.kept.tolist())
            why = sel.summary_text()
            say(f"{kind}: kept {len(sel.kept)} transmitters, dropped {len(sel.dropped)}"
                + (f" ({why})" if why else ""))
        del evidence
        for floor in floors:
            if floor not in seen:
                notes.append(f"floor {floor}: no {kind} rows")
                continue
            try:
                db = sums.pop(floor).result()
            except FingerprintError as err:
                notes.append(f"floor {floor}: no {kind} fingerprints ({err})")
                continue
            if kept is not None:
                db = db.restricted(sorted(kept))
            if len(db.fp) == 0:
                notes.append(f"floor {floor}: no {kind} rows of kept transmitters")
                continue
            fingerprints[(floor, kind)] = db
        samples[kind] = (model_rows, kept)
        release_free_memory()  # the walks' freed buffers
    model, model_kind, ble_model = None, "", None
    for kind in KINDS if params.floor_model else ():  # Wi-Fi first, BLE without Wi-Fi
        if kind not in samples:
            continue
        by_floor = samples[kind][0].tables(floors, samples[kind][1])
        heard = sum(len(v) > 0 for v in by_floor.values())
        if model is None and heard:
            model, model_kind = _fit_and_say(by_floor, kind, "", params, say), kind
        elif model is not None and heard >= 2:  # the BLE model beside the Wi-Fi one
            ble_model = _fit_and_say(by_floor, kind, ", beside Wi-Fi", params, say)
        elif model is not None and len(floors) > 1:
            notes.append(f"no {kind} floor model: {kind} rows on {heard} floor(s), two needed")
        del by_floor
    for n in notes:
        say(n)
    return SiteRadio(floors, devices, selections, fingerprints, model, model_kind, params,
                     notes, ble_model)


def _fit_and_say(by_floor: dict[str, pd.DataFrame], kind: str, what: str, params: RadioParams,
                 say: Callable[[str], None]) -> FloorModel:
    """The floor model of ``kind`` fitted and cross-validated on ``by_floor``, logged."""
    model = fit_floor_model(by_floor, cv_folds=params.floor_cv_folds, seed=params.seed,
                            feature=getattr(params, f"{kind}_floor_feature"))
    m = model.meta
    say(f"floor model ({kind}{what}, {model.feature}): {n_floors_text(len(model.floors))}, "
        f"{len(model.aps)} transmitters; cross-validated per scan "
        f"{format_share(m['cv_scan_accuracy'])}, per "
        f"walk {format_share(m['cv_walk_accuracy'])}")
    return model
