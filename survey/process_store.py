"""Run survey processing over a store and keep the results in it.

Processed tables live beside the raw ones::

    STORE/processed/catalog.parquet      one row per walk: status, summary, parameters
    STORE/processed/{samples,steps,legs,wifi,ble}/site=S/floor=F/<trace_id>-<hash12>.parquet

(``hash12``: of the raw file's sha256 and the hash of the walk's other inputs, see
:func:`inputs_sha256`, so that processing with other inputs writes other files and a run that
fails before its catalog is switched leaves the previous results whole.)

``wifi`` and ``ble`` are the raw rows with the positions (x_m, y_m) of their times added; rows
outside the walk's waypoint range are dropped (counted in the summary). A walk that cannot be
processed (no steps, no rotation vector, a single waypoint, ...) gets ``status = "skipped"`` and
the reason; nothing is lost. A walk whose raw part files cannot be read gets ``"failed"`` and is
tried again by every run. Processing is redone when the walk, the parameters, the floor plan or
its calibration session's fit change.

Calibration sessions are found across all the store's walks of a device model by the phone's
reported bias; walks that lack a trustworthy calibration use a fit pooled over their session.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from .errors import ProcessingError, StoreError
from .magcal import MagCalResult, fit_ellipsoid
from .process import ProcessedWalk, ProcessParams, calibration_sessions, process_walk, \
    reported_bias
from .publish import TMP_PREFIX, atomic_write_bytes, crash_point, fsync_dir, \
    remove_stale_temporaries
from .store import (SurveyStore, _arrow_column, _parquet_bytes, check_columns, files_match,
                    part_path, part_record, read_parquet_checked)

_MAG_COLUMNS = ["stream", "t_ms", "x", "y", "z", "bx", "by", "bz"]
PROCESSED_TABLES = ("samples", "steps", "legs", "wifi", "ble")
PROCESSED_CATALOG_COLUMNS = ("trace_id", "sha256", "site", "floor", "inputs_sha256", "status",
                             "reason", "session", "parts_json", "summary_json")


@dataclass
class ProcessReport:
    processed: list[str] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)
    unchanged: list[str] = field(default_factory=list)
    #: walks whose stored raw files cannot be read (missing or damaged part files): they are
    #: tried again by the next run; re-ingesting their files repairs them
    failed: dict[str, str] = field(default_factory=dict)
    sessions: dict[str, dict] = field(default_factory=dict)


def params_sha256(params: ProcessParams) -> str:
    return hashlib.sha256(params.to_json().encode()).hexdigest()


#: Calibration decisions made without the session's pooled fit (a walk with one of them does
#: not depend on the fit, so a new walk in its session does not process it again).
FIT_FREE_DECISIONS = ("device-calibrated", "uncalibrated-minus-device-bias")


def plan_sha256(reachable: object | None) -> str:
    """Hash of a floor plan's reachable area (its WKB; "" without a plan)."""
    import shapely

    return "" if reachable is None else hashlib.sha256(shapely.to_wkb(reachable)).hexdigest()


def inputs_sha256(params_sha: str, plan_sha: str, fit: MagCalResult | None) -> str:
    """What a walk's processed tables depend on besides its raw file: the processing
    parameters' hash, the floor plan's (:func:`plan_sha256`) and, for walks whose calibration
    used it or might, the pooled fit of their calibration session (None otherwise). A change
    to any of them processes the walk again."""
    h = hashlib.sha256(f"{params_sha}|plan:{plan_sha}".encode())
    if fit is not None:
        h.update(b"|fit:" + fit.status.encode() + np.concatenate(
            [np.ravel(fit.hard_iron_ut), np.ravel(fit.soft_iron)]).astype("<f8").tobytes())
    return h.hexdigest()


def _with_session(row: dict, key: str) -> dict:
    """A kept catalog row with its session key refreshed (the key names the session by its
    members' median bias, which other walks move; it is not an input of the tables)."""
    summary = json.loads(row["summary_json"])
    if "session" in summary:
        summary["session"] = key
    return {**row, "session": key, "summary_json": json.dumps(summary)}


def _position_rows(rows: pd.DataFrame, t_col: str, walk: ProcessedWalk) -> pd.DataFrame:
    """Rows inside the walk's waypoint range with the positions of their times added."""
    xy, inside = walk.position_at(rows[t_col].to_numpy(np.float64))
    out = rows[inside].drop(columns=["trace_id"], errors="ignore").reset_index(drop=True)
    out["x_m"], out["y_m"] = xy[inside, 0], xy[inside, 1]
    return out


def session_fits(store: SurveyStore, catalog: pd.DataFrame, max_samples: int = 20000,
                 seed: int = 0) -> tuple[dict[str, str], dict[str, MagCalResult],
                                         dict[str, str]]:
    """Session key of every walk of ``catalog``, an ellipsoid fit pooled over each session's
    raw samples, and the walks whose magnetometer columns cannot be read (trace id -> the
    store's error). Reads the magnetometer columns walk by walk. Each session's subsample
    is seeded by ``seed`` and the session's key, so a fit does not depend on which other
    sessions are fitted with it."""
    raw_of: dict[str, np.ndarray] = {}
    biases, models, unreadable = [], [], {}
    for row in catalog.itertuples(index=False):
        try:
            sensors = store.part("sensors", row, columns=_MAG_COLUMNS)
        except StoreError as err:
            unreadable[row.trace_id] = str(err)
            continue
        biases.append(reported_bias(sensors))
        models.append(row.device_model)
        unc = sensors[sensors["stream"] == "magnetic_field_uncalibrated"]
        raw_of[row.trace_id] = unc[["x", "y", "z"]].to_numpy(np.float64)
    keys = calibration_sessions(models, biases)
    sessions = dict(zip([t for t in catalog["trace_id"] if t not in unreadable], keys))
    pooled: dict[str, list[np.ndarray]] = {}
    for tid, key in sessions.items():
        if len(raw_of[tid]):
            pooled.setdefault(key, []).append(raw_of[tid])
    fits = {}
    for key, parts in sorted(pooled.items()):
        raw = np.concatenate(parts)
        if len(raw) > max_samples:
            rng = np.random.default_rng([seed, *hashlib.sha256(key.encode()).digest()[:8]])
            raw = raw[np.sort(rng.choice(len(raw), max_samples, replace=False))]
        if len(raw) >= 20:
            fits[key] = fit_ellipsoid(raw)
    return sessions, fits, unreadable


def _processed_parts_present(root, row: pd.Series) -> bool:
    """Whether every processed file of an ``ok`` catalog row is there with its recorded
    size and sha256."""
    return files_match({name: root / processed_part_path(
        name, row["site"], row["floor"], row["trace_id"], row["sha256"], row["inputs_sha256"])
        for name in PROCESSED_TABLES}, json.loads(row.get("parts_json") or "{}"))


def process_store(store: SurveyStore | str, *, site: str | None = None,
                  floor: str | None = None, floors: Sequence[str] | None = None,
                  params: ProcessParams = ProcessParams(),
                  reachable: dict[tuple[str, str], object] | None = None,
                  progress: Callable[[int, int], None] | None = None) -> ProcessReport:
    """Process every walk of the selected site/floor that is new or changed, or whose
    parameters, floor plan or calibration-session fit changed.

    Calibration sessions are fitted over every walk of the store made with the selection's
    phone models, so processing one floor gives what processing the whole store gives.

    Parameters
    ----------
    floors : sequence of str, optional
        Only these floors (partition names), besides ``floor``.
    reachable : dict, optional
        ``(site, floor) -> shapely geometry`` of the reachable area (for ``off_floor`` flags).
    """
    store = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
    root = store.root / "processed"
    cat = store.traces(site, floor)
    if floors is not None:
        cat = cat[cat["floor"].isin(list(floors))].reset_index(drop=True)
    pcat_path = root / "catalog.parquet"
    old = _read_processed_catalog(pcat_path)
    psha = params_sha256(params)
    report = ProcessReport()
    if not len(cat):
        return report
    everything = store.catalog()
    sessions, fits, unreadable = session_fits(
        store, everything[everything["device_model"].isin(cat["device_model"])])
    used = {sessions[t] for t in cat["trace_id"] if t in sessions}
    report.sessions = {k: {"status": f.status, "reason": f.reason,
                           "hard_iron_ut": np.round(f.hard_iron_ut, 2).tolist(),
                           "coverage": round(float(f.coverage), 3)}
                       for k, f in fits.items() if k in used}
    plan_shas = {k: plan_sha256(g) for k, g in (reachable or {}).items()}
    old_of = old.set_index("trace_id", drop=False)  # one row per walk (checked when read)
    new_rows = []
    with store.writer():  # one writer at a time for the whole store
        remove_stale_temporaries_under(root)
        for i, row in enumerate(cat.itertuples(index=False)):
            if progress and i:
                progress(i, len(cat))
            key = sessions.get(row.trace_id, "")
            plan_sha = plan_shas.get((row.site, row.floor), "")
            with_fit = inputs_sha256(psha, plan_sha, fits.get(key))
            base = {"trace_id": row.trace_id, "sha256": row.sha256, "site": row.site,
                    "floor": row.floor, "session": key, "parts_json": "",
                    "inputs_sha256": with_fit}
            d = old_of.loc[row.trace_id] if row.trace_id in old_of.index else None
            if d is not None and d["sha256"] == row.sha256 and row.trace_id not in unreadable:
                fit_free = d["status"] == "ok" and json.loads(d["summary_json"]).get(
                    "calibration") in FIT_FREE_DECISIONS
                same = d["inputs_sha256"] == (inputs_sha256(psha, plan_sha, None) if fit_free
                                              else with_fit)
                if same and (d["status"] == "skipped" or (
                        d["status"] == "ok" and _processed_parts_present(root, d))):
                    report.unchanged.append(row.trace_id)
                    new_rows.append(_with_session(d.to_dict(), key))
                    continue
            # one walk at a time: memory is bounded by the largest walk, not by the store
            try:
                if row.trace_id in unreadable:
                    raise StoreError(unreadable[row.trace_id])
                tables = {name: store.part(name, row) for name in ("sensors", "waypoints",
                                                                  "wifi", "ble")}
            except StoreError as err:
                report.failed[row.trace_id] = str(err)
                new_rows.append({**base, "status": "failed", "reason": str(err),
                                 "summary_json": "{}"})
                continue
            try:
                walk = process_walk(row.trace_id, tables["sensors"], tables["waypoints"], params,
                                    reachable=(reachable or {}).get((row.site, row.floor)),
                                    session_fit=fits.get(key))
            except ProcessingError as err:
                report.skipped[row.trace_id] = str(err)
                new_rows.append({**base, "status": "skipped", "reason": str(err),
                                 "summary_json": "{}"})
                continue
            outputs = {"samples": walk.samples, "steps": walk.steps, "legs": walk.legs,
                      "wifi": _position_rows(tables["wifi"], "scan_t_ms", walk),
                      "ble": _position_rows(tables["ble"], "t_ms", walk)}
            walk.summary["n_wifi_rows_positioned"] = len(outputs["wifi"])
            walk.summary["n_ble_rows_positioned"] = len(outputs["ble"])
            walk.summary["session"] = key
            if walk.summary.get("calibration") in FIT_FREE_DECISIONS:
                base["inputs_sha256"] = inputs_sha256(psha, plan_sha, None)
            parts = {}
            for name, frame in outputs.items():
                table = pa.table({c: _arrow_column(frame[c]) for c in frame.columns})
                rel = processed_part_path(name, row.site, row.floor, row.trace_id, row.sha256,
                                          base["inputs_sha256"])
                data = _parquet_bytes(table)
                atomic_write_bytes(root / rel, data, overwrite=True, sync_dir=False)
                parts[name] = part_record(data, table.num_rows)
            report.processed.append(row.trace_id)
            new_rows.append({**base, "status": "ok", "reason": "",
                             "parts_json": json.dumps(parts, sort_keys=True),
                             "summary_json": json.dumps(walk.summary, default=_json_default)})
        if progress:
            progress(len(cat), len(cat))
        for folder in {(root / part_path(t, r["site"], r["floor"], "x", "0")).parent
                       for r in new_rows for t in PROCESSED_TABLES}:
            fsync_dir(folder)
        keep = old[~old["trace_id"].isin([r["trace_id"] for r in new_rows])]
        pcat = pd.concat([keep, pd.DataFrame(new_rows)], ignore_index=True)
        pcat = pcat[list(PROCESSED_CATALOG_COLUMNS)].astype("str")
        pcat = pcat.sort_values(["site", "floor", "trace_id"], kind="stable")
        crash_point("process:before-catalog")
        table = pa.Table.from_pandas(pcat, preserve_index=False).replace_schema_metadata(None)
        atomic_write_bytes(pcat_path, _parquet_bytes(table), overwrite=True)
        _remove_unreferenced(root, pcat)
    return report


def remove_stale_temporaries_under(root) -> None:
    """Remove the temporaries a killed run left in ``processed/`` and its tables' folders
    (the caller holds the store's writer lock, so no live writer has any there)."""
    remove_stale_temporaries(root)
    for table in PROCESSED_TABLES:
        base = root / table
        if base.exists():
            for p in base.rglob(TMP_PREFIX + "*"):
                p.unlink(missing_ok=True)


def _read_processed_catalog(path) -> pd.DataFrame:
    """The processed catalog as stored (all text), checked. One written before
    ``inputs_sha256`` (its files named by ``params_sha256``) is read with that hash as the
    files' name and no part hashes: its walks are readable, and processed again when next
    selected."""
    empty = pd.DataFrame({c: pd.Series([], dtype="str") for c in PROCESSED_CATALOG_COLUMNS})
    if not path.exists():
        return empty
    table = read_parquet_checked(path, what="processed catalog")
    if "inputs_sha256" not in table.column_names and "params_sha256" in table.column_names:
        table = table.append_column("inputs_sha256", table.column("params_sha256"))
        table = table.append_column("parts_json", pa.array([""] * table.num_rows))
    check_columns(table, PROCESSED_CATALOG_COLUMNS, path, "processed catalog")
    cat = table.select(list(PROCESSED_CATALOG_COLUMNS)).to_pandas()
    dup = cat["trace_id"][cat["trace_id"].duplicated()]
    if len(dup):
        raise StoreError(f"{path}: damaged processed catalog: trace id {dup.iloc[0]!r} has "
                         "several rows")
    return cat


def processed_part_path(table: str, site: str, floor: str, trace_id: str, sha256: str,
                        inputs_sha: str) -> str:
    """Relative path (under ``processed/``) of a walk's processed ``table``, named by its raw
    file's ``sha256`` and the hash of its other inputs ``inputs_sha`` (:func:`inputs_sha256`)
    together."""
    both = hashlib.sha256(f"{sha256}:{inputs_sha}".encode()).hexdigest()
    return part_path(table, site, floor, trace_id, both)


def _json_default(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serializable: {type(value)}")


def _remove_unreferenced(root, pcat: pd.DataFrame) -> None:
    live = {processed_part_path(t, r.site, r.floor, r.trace_id, r.sha256, r.inputs_sha256)
            for r in pcat[pcat["status"] == "ok"].itertuples(index=False)
            for t in PROCESSED_TABLES}
    for table in PROCESSED_TABLES:
        base = root / table
        if base.exists():
            for p in base.rglob("*.parquet"):
                if str(p.relative_to(root)) not in live:
                    p.unlink()


def processed_catalog(store: SurveyStore | str) -> pd.DataFrame:
    """The processed catalog (one row per walk), with the summary parsed into a dict column."""
    store = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
    path = store.root / "processed" / "catalog.parquet"
    if not path.exists():
        raise ProcessingError(f"{store.root}: not processed yet; run `indoormap process`")
    cat = _read_processed_catalog(path)
    cat["summary"] = [json.loads(s) for s in cat["summary_json"]]
    return cat


def processed_walks(store: SurveyStore | str, *, site: str | None = None,
                    floor: str | None = None) -> pd.DataFrame:
    """Processed catalog rows (:func:`processed_catalog`) of the walks of the selection that
    processed ``ok``."""
    cat = processed_catalog(store)
    cat = cat[cat["status"] == "ok"]
    if site is not None:
        cat = cat[cat["site"] == site]
    if floor is not None:
        cat = cat[cat["floor"] == floor]
    return cat.reset_index(drop=True)


def processed_part(store: SurveyStore | str, name: str, walk: pd.Series, *,
                   text_as_category: bool = False,
                   columns: Sequence[str] | None = None) -> pd.DataFrame:
    """One processed table of one walk (``walk``: a row of :func:`processed_walks`). Reading
    walk by walk lets callers reduce each walk before the next is read, so memory is bounded
    by what they keep, not by the floor. ``text_as_category``: text columns come as pandas
    categoricals (no Python string per row). ``columns``: read only these."""
    if name not in PROCESSED_TABLES:
        raise ProcessingError(f"unknown processed table {name!r}; expected {PROCESSED_TABLES}")
    store = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
    table = _processed_arrow(store, name, walk, columns)
    if text_as_category:
        for i, f in enumerate(table.schema):
            if pa.types.is_string(f.type) or pa.types.is_large_string(f.type):
                table = table.set_column(i, f.name, pc.dictionary_encode(table.column(i)))
    return table.to_pandas()


def _processed_arrow(store: SurveyStore, name: str, walk: pd.Series,
                     columns: Sequence[str] | None = None) -> pa.Table:
    """One processed file of a walk as Arrow, checked against its catalog row."""
    return read_parquet_checked(store.root / "processed" / processed_part_path(
        name, walk["site"], walk["floor"], walk["trace_id"], walk["sha256"],
        walk["inputs_sha256"]),
        None if columns is None else list(columns), what="processed part",
        expect=json.loads(walk["parts_json"] or "{}").get(name))


def verify_processed(store: SurveyStore | str,
                     progress: Callable[[int, int], None] | None = None) -> dict[str, str]:
    """Read every processed file the processed catalog names (walks that processed ``ok``),
    checked; returns ``{trace_id: problem}`` of the walks that fail (empty: all whole, or
    nothing processed yet)."""
    store = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
    if not (store.root / "processed" / "catalog.parquet").exists():
        return {}
    walks = processed_walks(store)
    problems = {}
    for i, (_, walk) in enumerate(walks.iterrows()):
        try:
            for name in PROCESSED_TABLES:
                _processed_arrow(store, name, walk)
        except StoreError as err:
            problems[walk["trace_id"]] = str(err)
        if progress:
            progress(i + 1, len(walks))
    return problems


def processed_table(store: SurveyStore | str, name: str, *, site: str | None = None,
                    floor: str | None = None) -> pd.DataFrame:
    """One processed table over the walks that processed ``ok``, with a ``trace_id`` column."""
    store = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
    frames = []
    for _, walk in processed_walks(store, site=site, floor=floor).iterrows():
        frame = processed_part(store, name, walk)
        frame.insert(0, "trace_id", walk["trace_id"])
        frames.append(frame)
    if not frames:
        raise ProcessingError(f"no processed walks for site={site!r} floor={floor!r}")
    return pd.concat(frames, ignore_index=True)
