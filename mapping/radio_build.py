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
   :class:`localize.floor_classifier.FloorClassifier`.

A floor without any row of a kind simply has no tables of that kind (reported in
``metrics["radio"]``); a site without any radio row has no radio tables at all.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd
import pyarrow as pa
from numpy.typing import NDArray

from survey.errors import ProcessingError
from survey.memory import release_free_memory
from survey.store import SurveyStore
from survey.process_store import processed_part, processed_walks

from .ap_selection import APSelection, APSelectionParams, select_aps
from .bundle_writer import BundleContent
from .device_calibration import DEVICE_TABLE_COLUMNS, calibrate_devices
from .errors import FingerprintError
from .fingerprints import DEFAULT_CELL_M, FingerprintDB, build_fingerprints
from .floor_model import FloorModel, fit_floor_model
from .radio_scans import OBS_COLUMNS, ble_observations, split_by, wifi_observations

__all__ = ["KINDS", "RadioParams", "SiteRadio", "build_site_radio", "calibrated", "site_observations",
           "site_radio"]

KINDS = ("wifi", "ble")


@dataclass(frozen=True)
class RadioParams:
    """Radio-map parameters (m, ms)."""

    cell_m: float = DEFAULT_CELL_M
    ble_window_ms: int = 2000
    select_aps: bool = True
    ap_selection: APSelectionParams = field(default_factory=APSelectionParams)
    calibrate_devices: bool = True
    floor_model: bool = True
    floor_cv_folds: int = 5
    seed: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


def _table(frame: pd.DataFrame) -> pa.Table:
    return pa.Table.from_pandas(frame.reset_index(drop=True), preserve_index=False)


def site_observations(store: SurveyStore, site: str | None, floors: Sequence[str], kind: str,
                      *, ble_window_ms: int = 2000,
                      exclude_walks: Collection[str] = ()) -> pd.DataFrame:
    """Observation table (:mod:`mapping.radio_scans`) of ``kind`` over ``floors`` with a
    ``floor`` column and an ``ssid`` column (Wi-Fi; "" for BLE); rows of any age.
    RSSI outside the phone range is dropped (counted by the reader's checks upstream).
    Walks whose trace id is in ``exclude_walks`` are left out.

    Reads the processed rows walk by walk and keeps only each walk's observations, with the
    text columns (``trace_id``, ``ap``, ``ssid``, ``floor``) as categoricals: about 60 bytes
    per observation row, so memory grows with the observations only, never with the raw rows
    and their text."""
    columns = (*OBS_COLUMNS, "floor")
    parts: dict[str, list[np.ndarray]] = {c: [] for c in columns}  # per column, per walk
    ssid_of, n_scans = {}, 0
    codes = {"trace_id": {}, "ap": {}, "floor": {}}
    try:
        walks = processed_walks(store, site=site)
    except ProcessingError:  # never processed: no rows
        walks = pd.DataFrame(columns=["floor", "trace_id"])
    walks = walks[~walks["trace_id"].isin(list(exclude_walks))]
    for floor in floors:
        for _, r in walks[walks["floor"] == floor].iterrows():
            rows = processed_part(store, kind, r, text_as_category=True)
            if len(rows) == 0:
                continue
            rows.insert(0, "trace_id", r["trace_id"])
            if kind == "wifi":
                obs = wifi_observations(rows, invalid="drop")
                first = rows.drop_duplicates("bssid")  # an AP's SSID: that of its first row
                for bssid, ssid in zip(first["bssid"].astype(str).str.lower(), first["ssid"]):
                    ssid_of.setdefault(bssid, str(ssid))
            else:
                obs = ble_observations(rows, window_ms=ble_window_ms, invalid="drop")
            walk_scans = int(obs["scan_id"].max()) + 1 if len(obs) else 0  # numbered from 0
            obs["scan_id"] += n_scans  # unique over the site
            n_scans += walk_scans
            obs["floor"] = floor
            for col, table in codes.items():
                obs[col] = _codes(obs[col], table)
            for col in columns:
                parts[col].append(obs[col].to_numpy())
    if not parts["scan_id"]:
        return pd.DataFrame(columns=[*OBS_COLUMNS, "ssid", "floor"])
    # One column at a time, each column's walk pieces freed as soon as it is joined: the peak
    # is the table plus one column, not twice the table.
    data = {}
    for col in columns:
        joined = np.concatenate(parts.pop(col))
        data[col] = (pd.Categorical.from_codes(joined, list(codes[col])) if col in codes
                     else joined)
    # SSID of each row's AP (Wi-Fi), coded through the AP's code
    ssid_code, ssids = pd.factorize(np.array([ssid_of.get(ap, "") for ap in codes["ap"]],
                                             dtype=object))
    data["ssid"] = pd.Categorical.from_codes(ssid_code[data["ap"].codes], ssids)
    data["floor"] = data.pop("floor")
    table = pd.DataFrame(data, copy=False)
    release_free_memory()  # the walks' freed buffers
    return table


def _codes(values: pd.Series, table: dict[str, int]) -> NDArray[np.int32]:
    """Integer codes of ``values`` in ``table`` (new values appended to it)."""
    idx, uniques = pd.factorize(values)
    lookup = np.array([table.setdefault(str(u), len(table)) for u in uniques], dtype=np.int32)
    return lookup[idx]


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
    notes : list of str
        What was missing (floors without Wi-Fi, ...), for the build log and the manifest.
    """

    floors: list[str]
    devices: pd.DataFrame
    selections: dict[str, APSelection]
    fingerprints: dict[tuple[str, str], FingerprintDB]
    floor_model: FloorModel | None
    floor_model_kind: str
    params: RadioParams
    notes: list[str] = field(default_factory=list)

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
                          "scans": int(db.rp["n_scans"].sum()), "cell_m": db.cell_m})
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
        if self.floor_model is not None:
            t = self.floor_model.to_tables()
            tables["floor_coef"], tables["floor_intercept"] = _table(t["coef"]), _table(
                t["intercept"])
            tables["floor_meta"] = _table(t["meta"])
            m = self.floor_model.meta
            metrics["floor_model"] = {
                "kind": self.floor_model_kind, "floors": self.floor_model.floors.tolist(),
                "transmitters": int(len(self.floor_model.aps)),
                "cv_folds": int(m.get("cv_folds", 0)),
                **{k: (None if not np.isfinite(m.get(k, np.nan)) else float(m[k]))
                   for k in ("cv_scan_accuracy", "cv_sequence_accuracy", "cv_walk_accuracy")}}
        return BundleContent(site_id=site_id, floor_id="", floor_name="", kind="site",
                             tables=tables, build={**(build or {}),
                                                   "radio_params": self.params.to_dict()},
                             metrics=metrics)


def calibrated(obs: pd.DataFrame, device_of: pd.Series, devices: pd.DataFrame) -> pd.DataFrame:
    """``obs`` with every walk's RSSI mapped through its phone model's ``k, b`` (dBm); models
    not in the device table are left as they are."""
    table = devices.set_index("device_model")
    if ((table["k"] == 1.0) & (table["b"] == 0.0)).all():
        return obs
    traces = pd.Series(pd.unique(obs["trace_id"]))
    model = traces.map(device_of)
    per_trace = pd.DataFrame({"k": model.map(table["k"]).fillna(1.0).to_numpy(),
                              "b": model.map(table["b"]).fillna(0.0).to_numpy()},
                             index=traces.to_numpy())
    idx = per_trace.index.get_indexer(obs["trace_id"])
    k, b = per_trace["k"].to_numpy()[idx], per_trace["b"].to_numpy()[idx]
    return obs.assign(rssi_dbm=k * obs["rssi_dbm"].to_numpy() + b)  # other columns shared


def build_site_radio(store: SurveyStore | str, floors: Sequence[str], *,
                     site: str | None = None, params: RadioParams = RadioParams(),
                     exclude_walks: Collection[str] = (),
                     progress: Callable[[str], None] | None = None) -> SiteRadio:
    """Device table, AP selection, fingerprints and floor model of a site's floors, from all
    their processed walks but ``exclude_walks`` (trace ids)."""
    store = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
    floors = [str(f) for f in floors]
    cat = store.traces(site)
    device_of = cat.set_index("trace_id")["device_model"].fillna("").astype(str)
    # no local name for the tables: site_radio may free each one once it has filtered it
    return site_radio({kind: site_observations(store, site, floors, kind,
                                               ble_window_ms=params.ble_window_ms,
                                               exclude_walks=exclude_walks)
                       for kind in KINDS}, device_of, floors, params=params, progress=progress)


def site_radio(obs: dict[str, pd.DataFrame], device_of: pd.Series, floors: Sequence[str], *,
               params: RadioParams = RadioParams(),
               progress: Callable[[str], None] | None = None) -> SiteRadio:
    """:func:`build_site_radio` on observation tables (pure computation).

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
    say = progress or (lambda msg: None)
    floors = [str(f) for f in floors]
    obs = dict(obs)
    notes: list[str] = []
    devices = pd.DataFrame({c: [] for c in DEVICE_TABLE_COLUMNS})
    if len(obs.get("wifi", ())) and params.calibrate_devices:
        devices = calibrate_devices(obs["wifi"], device_of, floor_column="floor")
        fitted = devices[devices["method"] == "offline"]
        say("devices: reference " + str(devices["device_model"].iloc[0]) + "; "
            + (", ".join(f"{r.device_model} k={r.k:.3f} b={r.b:+.1f} dB"
                         for r in fitted.itertuples()) or "no other model fitted"))
    selections: dict[str, APSelection] = {}
    fingerprints: dict[tuple[str, str], FingerprintDB] = {}
    for kind in KINDS:
        o = obs.pop(kind, None)  # the only reference: each filtered table replaces its input
        if o is None or len(o) == 0:
            notes.append(f"no {kind} rows on any floor")
            obs[kind] = pd.DataFrame(columns=["floor"])
            continue
        if len(devices) and kind == "wifi":
            o = calibrated(o, device_of, devices)
        if params.select_aps:
            ssid = o.drop_duplicates("ap").set_index("ap")["ssid"] if kind == "wifi" else None
            sel = select_aps(o, ssid=ssid, floor_column="floor", floor_order=floors,
                             params=params.ap_selection)
            selections[kind] = sel
            o = o[o["ap"].isin(set(sel.kept.tolist()))]
            say(f"{kind}: kept {len(sel.kept)} transmitters, dropped {len(sel.dropped)} "
                f"{sel.summary()}")
        by_floor = split_by(o, "floor")
        for floor in floors:
            part = by_floor.get(floor, o.iloc[:0])
            if len(part) == 0:
                notes.append(f"floor {floor}: no {kind} rows")
                continue
            try:
                fingerprints[(floor, kind)] = build_fingerprints(part, kind=kind,
                                                                 cell_m=params.cell_m)
            except FingerprintError as err:
                notes.append(f"floor {floor}: no {kind} fingerprints ({err})")
        obs[kind] = o
    model, model_kind = None, ""
    for kind in KINDS if params.floor_model else ():  # Wi-Fi first, BLE without Wi-Fi
        by_floor = split_by(obs[kind], "floor")
        by_floor = {f: by_floor.get(f, obs[kind].iloc[:0]) for f in floors}
        if any(len(v) for v in by_floor.values()):
            model = fit_floor_model(by_floor, cv_folds=params.floor_cv_folds, seed=params.seed)
            model_kind = kind
            m = model.meta
            say(f"floor model ({kind}): {len(model.floors)} floors, {len(model.aps)} "
                f"transmitters; cross-validated per scan {m['cv_scan_accuracy']:.4f}, per walk "
                f"{m['cv_walk_accuracy']:.4f}")
            break
    for n in notes:
        say(n)
    return SiteRadio(floors, devices, selections, fingerprints, model, model_kind, params,
                     notes)
