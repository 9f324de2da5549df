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
The sessions' keys and fits are kept in ``STORE/processed/session_fits.json`` with the hash of
what they were computed from (:func:`store_session_fits`), so that a run over unchanged walks
does not read their magnetometer columns again.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import json
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from . import __version__
from .errors import ProcessingError, StoreError
from .magcal import MagCalResult, fit_ellipsoid
from .process import MAX_WAYPOINT_OUTSIDE_SENSORS_S, ProcessedWalk, ProcessParams, \
    calibration_sessions, process_walk, reported_bias
from .publish import TMP_PREFIX, atomic_write_bytes, crash_point, fsync_dir, \
    remove_stale_temporaries
from .regular_files import read_regular
from .store import (SurveyStore, _arrow_column, _parquet_bytes, check_columns, files_match,
                    part_path, part_record, read_parquet_checked, remove_empty_folders)

_MAG_COLUMNS = ["stream", "t_ms", "x", "y", "z", "bx", "by", "bz"]
PROCESSED_TABLES = ("samples", "steps", "legs", "wifi", "ble")
PROCESSED_CATALOG_COLUMNS = ("trace_id", "sha256", "site", "floor", "inputs_sha256", "status",
                             "reason", "session", "parts_json", "summary_json")
#: The session-fit cache, under ``processed/`` (:func:`store_session_fits`).
SESSION_CACHE = "session_fits.json"
SESSION_CACHE_FORMAT = "indoormap-session-fits"
#: Largest session-fit cache read (a few kB per calibration session).
MAX_SESSION_CACHE_BYTES = 256 * 1024**2
#: Version of what the session-fit cache holds. Bump it when how a fit is written changes:
#: caches of other versions are fitted again. A change to the fitting code itself needs no
#: bump: the key holds the sha256 of its source files (:func:`_fit_code_sha256`).
SESSION_FIT_VERSION = 1


@dataclass
class ProcessReport:
    processed: list[str] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)
    unchanged: list[str] = field(default_factory=list)
    #: walks whose stored raw files cannot be read (missing or damaged part files): they are
    #: tried again by the next run; re-ingesting their files repairs them
    failed: dict[str, str] = field(default_factory=dict)
    sessions: dict[str, dict] = field(default_factory=dict)
    #: problems met and worked around (a damaged session-fit cache, ignored and refitted)
    warnings: list[str] = field(default_factory=list)


#: Version of what processing computes from the same inputs and parameters; part of every
#: walk's inputs hash, so a store processed by an older version is processed again. 2: a
#: waypoint far outside the walk's sensor rows is dropped
#: (:data:`survey.process.MAX_WAYPOINT_OUTSIDE_SENSORS_S`). 3 (session 51): a bias of 0 on
#: every axis is no estimate, no gyroscope turn is integrated over a gap, and sensors in
#: another unit are refused (:mod:`survey.sensor_units`, session 50).
PROCESS_VERSION = 3


def params_sha256(params: ProcessParams) -> str:
    """Hash of the processing parameters and :data:`PROCESS_VERSION`."""
    return hashlib.sha256(f"process v{PROCESS_VERSION}|{params.to_json()}".encode()).hexdigest()


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
    sessions are fitted with it. Uncached: :func:`store_session_fits` keeps the results."""
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


# ---- session-fit cache ------------------------------------------------------------------------
#
# processed/session_fits.json keeps, per device group (the model name the session keys carry),
# the session key of each walk and the session fits, with the hash of everything they were
# computed from (:func:`_group_inputs_sha256`). A run whose hash matches takes them from there
# instead of reading every walk's magnetometer columns again. Floats are kept as the hex of
# their little-endian float64 bytes, so a cached fit is the computed one bit for bit.

_FIT_TEXT = ("status", "method", "reason")
_FIT_FLOATS = ("field_strength_ut", "residual_rms_ut", "condition_number", "coverage")
_FIT_ARRAYS = {"hard_iron_ut": (3,), "soft_iron": (3, 3), "hard_iron_se_ut": (3,),
               "earth_field_ut": (3,)}


@dataclass
class SessionFits:
    """What :func:`store_session_fits` gives: each walk's session key, the session fits, the
    walks whose magnetometer columns cannot be read (trace id -> the store's error), the
    cache's new content (None: the file is current) and the problems met (a damaged cache)."""

    sessions: dict[str, str]
    fits: dict[str, MagCalResult]
    unreadable: dict[str, str]
    cache: dict | None = None
    warnings: list[str] = field(default_factory=list)


def device_group(model: str) -> str:
    """The name :func:`survey.process.calibration_sessions` gives a device model in its
    session keys (``model or "unknown"``): walks of models of one name are fitted together."""
    return model or "unknown"


def _defaults(fn) -> dict:
    return {k: p.default for k, p in inspect.signature(fn).parameters.items()
            if p.default is not inspect.Parameter.empty}


def _fit_code_sha256() -> str:
    """sha256 of the source files of the code the session fit runs (``reported_bias``,
    ``calibration_sessions``, ``fit_ellipsoid``, :func:`session_fits`), so that an edit to any
    of them refits the sessions without a version bump."""
    h = hashlib.sha256()
    for fn in (reported_bias, calibration_sessions, fit_ellipsoid, session_fits):
        h.update(f"{fn.__qualname__}\0".encode())  # the file names the module
        try:
            h.update(Path(inspect.getsourcefile(fn) or "").read_bytes())
        except (TypeError, OSError):  # no source (a frozen build): the version must do
            h.update(b"no source")
    return h.hexdigest()


def _sensors_record(row) -> dict | None:
    """The sensors part's recorded sha256/size/rows of a catalog row (None: schema 1)."""
    try:
        rec = json.loads(row.parts_json or "{}").get("sensors")
    except (ValueError, AttributeError):
        return None
    return rec if isinstance(rec, dict) else None


def _fit_inputs(max_samples: int, seed: int) -> dict:
    """What every device group's session fit depends on besides its walks: this code's
    :data:`SESSION_FIT_VERSION`, source and libraries, and the fit's parameters."""
    import scipy

    return {"version": SESSION_FIT_VERSION,
            "software": {"indoormap": __version__, "numpy": np.__version__,
                         "scipy": scipy.__version__, "code": _fit_code_sha256()},
            "params": {"max_samples": max_samples, "seed": seed,
                       "calibration_sessions": _defaults(calibration_sessions),
                       "fit_ellipsoid": _defaults(fit_ellipsoid)}}


def _group_inputs_sha256(store: SurveyStore, rows: pd.DataFrame, common: dict) -> str | None:
    """Hash of what a device group's session keys and fits depend on: ``common``
    (:func:`_fit_inputs`), the models, and each walk (in the order the fit reads them) with
    its raw file's and sensors part's sha256. None when a walk's sensors part is not there as
    recorded (missing, changed, or schema 1 without a recorded hash): the walks are then read,
    which names the unreadable ones."""
    walks = []
    for row in rows.itertuples(index=False):
        rec = _sensors_record(row)
        path = store.root / part_path("sensors", row.site, row.floor, row.trace_id, row.sha256)
        if rec is None or not files_match({"sensors": path}, {"sensors": rec}):
            return None
        walks.append([row.site, row.floor, row.trace_id, row.sha256, rec["sha256"]])
    inputs = {**common, "models": sorted(set(rows["device_model"])), "walks": walks}
    return hashlib.sha256(json.dumps(inputs, sort_keys=True, default=repr).encode()).hexdigest()


def _f8(value) -> str:
    return np.asarray(value, dtype="<f8").tobytes().hex()


def _from_f8(text: str, shape: tuple[int, ...]) -> np.ndarray:
    data = bytes.fromhex(text)
    if len(data) != 8 * int(np.prod(shape)):
        raise ValueError(f"{len(data)} bytes for a float64 array of shape {shape}")
    return np.frombuffer(data, dtype="<f8").astype(np.float64).reshape(shape)


def _encode_fit(fit: MagCalResult) -> dict:
    out = {name: getattr(fit, name) for name in _FIT_TEXT}
    out["n_samples"] = int(fit.n_samples)
    out.update({name: _f8(getattr(fit, name)) for name in (*_FIT_FLOATS, *_FIT_ARRAYS)})
    return out


def _decode_fit(doc: dict) -> MagCalResult:
    names = {f.name for f in dataclasses.fields(MagCalResult)}
    if not isinstance(doc, dict) or set(doc) != names:
        raise ValueError("a fit without the fields of MagCalResult")
    if not all(isinstance(doc[n], str) for n in (*_FIT_TEXT, *_FIT_FLOATS, *_FIT_ARRAYS)) \
            or type(doc["n_samples"]) is not int:
        raise ValueError("a fit field of the wrong type")
    return MagCalResult(
        **{n: doc[n] for n in _FIT_TEXT}, n_samples=doc["n_samples"],
        **{n: float(_from_f8(doc[n], (1,))[0]) for n in _FIT_FLOATS},
        **{n: _from_f8(doc[n], shape) for n, shape in _FIT_ARRAYS.items()})


def _groups_sha256(groups: dict) -> str:
    return hashlib.sha256(json.dumps(groups, sort_keys=True, separators=(",", ":"))
                          .encode()).hexdigest()


def _read_session_cache(path: Path) -> tuple[dict, dict, str | None]:
    """The session-fit cache: its groups as stored, decoded (group -> ``{"key", "sessions",
    "fits"}``), and the problem that made it unusable (None: whole, or absent)."""
    if not path.exists():
        return {}, {}, None
    try:
        doc = json.loads(read_regular(path, MAX_SESSION_CACHE_BYTES))  # no FIFO wait
        if not isinstance(doc, dict) or doc.get("format") != SESSION_CACHE_FORMAT:
            raise ValueError(f"not an {SESSION_CACHE_FORMAT} file")
        if doc.get("version") != SESSION_FIT_VERSION:
            return {}, {}, (f"session-fit cache of version {doc.get('version')!r}, not "
                            f"{SESSION_FIT_VERSION}")
        groups = doc["groups"]
        if not isinstance(groups, dict) or doc.get("sha256") != _groups_sha256(groups):
            raise ValueError("content does not match its sha256")
        decoded = {}
        for name, entry in groups.items():
            sessions, fits = entry["sessions"], entry["fits"]
            if not (isinstance(entry["key"], str) and isinstance(sessions, dict)
                    and isinstance(fits, dict)
                    and all(isinstance(v, str) for v in sessions.values())):
                raise ValueError(f"malformed entry {name!r}")
            decoded[name] = {"key": entry["key"], "sessions": sessions,
                             "fits": {k: _decode_fit(f) for k, f in fits.items()}}
    except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError) as err:
        return {}, {}, f"damaged session-fit cache ({type(err).__name__}: {err})"
    return groups, decoded, None


def store_session_fits(store: SurveyStore, models: Iterable[str], max_samples: int = 20000,
                       seed: int = 0) -> SessionFits:
    """:func:`session_fits` over every walk of the store whose device group
    (:func:`device_group`) is one of ``models``' groups, each group taken from the session-fit
    cache (``processed/session_fits.json``) when the hash of its inputs matches, else fitted
    from the walks' magnetometer columns. Groups are fitted apart: sessions never span two
    groups, and each session's subsample is seeded by its key, so the result is what one
    :func:`session_fits` over all the walks gives. A damaged cache is ignored (a warning) and
    written anew; :attr:`SessionFits.cache` is the content to write, or None when the file
    needs no change."""
    everything = store.catalog()
    path = store.root / "processed" / SESSION_CACHE
    stored, cached, problem = _read_session_cache(path)
    out = SessionFits({}, {}, {})
    if problem:
        out.warnings.append(f"{path}: {problem}; ignored, the sessions are fitted again")
    group_of = everything["device_model"].map(device_group)
    present = set(group_of)
    new = {name: entry for name, entry in stored.items() if name in present}
    changed = problem is not None or len(new) != len(stored)
    sessions, fits = {}, {}
    common = _fit_inputs(max_samples, seed)  # the code's sources are read once, not per group
    for name in sorted({device_group(m) for m in models} & present):
        rows = everything[group_of == name]
        key = _group_inputs_sha256(store, rows, common)
        hit = cached.get(name)
        if key is not None and hit is not None and hit["key"] == key \
                and set(hit["sessions"]) == set(rows["trace_id"]):
            sessions.update(hit["sessions"])
            fits.update(hit["fits"])
            continue
        s, f, unreadable = session_fits(store, rows, max_samples, seed)
        sessions.update(s)
        fits.update(f)
        out.unreadable.update(unreadable)
        if key is not None and not unreadable:
            new[name] = {"key": key, "sessions": s,
                         "fits": {k: _encode_fit(v) for k, v in f.items()}}
            changed = True
    order = list(everything["trace_id"])
    out.sessions = {t: sessions[t] for t in order if t in sessions}
    out.unreadable = {t: out.unreadable[t] for t in order if t in out.unreadable}
    out.fits = {k: fits[k] for k in sorted(fits)}
    out.cache = new if changed else None
    return out


def _write_session_cache(path: Path, groups: dict) -> None:
    """Write the session-fit cache atomically (the caller holds the store's writer lock)."""
    doc = {"format": SESSION_CACHE_FORMAT, "version": SESSION_FIT_VERSION,
           "sha256": _groups_sha256(groups), "groups": groups}
    atomic_write_bytes(path, json.dumps(doc, sort_keys=True, indent=1).encode(),
                       overwrite=True, crash="process:session-cache-before-rename")
    crash_point("process:session-cache-after-rename")


def verify_session_cache(store: SurveyStore | str) -> str | None:
    """The problem of the store's session-fit cache (None: whole, or absent). Its sha256,
    format and every fit are checked; whether it is current is not (a run refits what
    changed), nor are the fits recomputed."""
    store = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
    path = store.root / "processed" / SESSION_CACHE
    problem = _read_session_cache(path)[2]
    return None if problem is None else f"{path}: {problem}"


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
    phone models, so processing one floor gives what processing the whole store gives; the
    fits of device models whose walks did not change come from the session-fit cache
    (:func:`store_session_fits`), which the run rewrites when it refitted any.

    Parameters
    ----------
    floors : sequence of str, optional
        Only these floors (partition names), besides ``floor``.
    reachable : dict, optional
        ``(site, floor) -> shapely geometry`` of the reachable area (for ``off_floor`` flags).
    """
    store = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
    with store.writer():  # one writer at a time, from reading the catalogs to writing one
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
        found = store_session_fits(store, cat["device_model"])
        sessions, fits, unreadable = found.sessions, found.fits, found.unreadable
        report.warnings += found.warnings
        used = {sessions[t] for t in cat["trace_id"] if t in sessions}
        report.sessions = {k: {"status": f.status, "reason": f.reason,
                               "hard_iron_ut": np.round(f.hard_iron_ut, 2).tolist(),
                               "coverage": round(float(f.coverage), 3)}
                           for k, f in fits.items() if k in used}
        plan_shas = {k: plan_sha256(g) for k, g in (reachable or {}).items()}
        old_of = old.set_index("trace_id", drop=False)  # one row per walk (checked when read)
        new_rows = []
        remove_stale_temporaries_under(root)
        if found.cache is not None:
            _write_session_cache(root / SESSION_CACHE, found.cache)
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
            if (d is not None and d["sha256"] == row.sha256 and row.trace_id not in unreadable
                    and (d["site"], d["floor"]) == (row.site, row.floor)):  # not moved
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
            except ProcessingError as err:  # kept without the walk's id, which it is of
                why = str(err).removeprefix(f"{row.trace_id}: ")
                report.skipped[row.trace_id] = why
                new_rows.append({**base, "status": "skipped", "reason": why,
                                 "summary_json": "{}"})
                continue
            stray = walk.summary["waypoints_outside_sensors_t_ms"]
            if stray:
                report.warnings.append(
                    f"{row.trace_id}: {len(stray)} waypoint(s) more than "
                    f"{MAX_WAYPOINT_OUTSIDE_SENSORS_S:g} s outside the walk's sensor rows "
                    f"dropped (t_ms {', '.join(map(str, stray[:5]))}"
                    + (" ..." if len(stray) > 5 else "") + ")")
            missed = walk.legs["flags"].str.contains("waypoint", regex=False)
            if missed.any():  # a mis-clicked waypoint bends the walk's positions silently
                report.warnings.append(
                    f"{row.trace_id}: the step track misses the waypoints of {int(missed.sum())}"
                    f" of its {len(missed)} legs by more than "
                    f"{params.positions.max_waypoint_residual_m:g} m: a waypoint clicked at "
                    "the wrong place or time? `indoormap survey-report --legs` lists them")
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
            remove_empty_folders(base)  # a walk moved to another floor empties its old one


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


def walks_per_site(walks: pd.DataFrame) -> str:
    """``"A: 3 walks, B: 1 walk"``: how many of ``walks`` (rows with a ``site`` column) each
    site has, most first; what a refusal to merge several sites' walks names."""
    counts = walks["site"].value_counts()
    return ", ".join(f"{s}: {n} walk{'s' * (n > 1)}" for s, n in counts.items())


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
        raise ProcessingError(f"no processed walks for site={site!r} floor={floor!r}; "
                              f"{processed_floors_text(store)}")
    return pd.concat(frames, ignore_index=True)


def processed_floors_text(store: SurveyStore | str) -> str:
    """``"the store has processed walks of site S floors F1 (3), F2 (1)"``, or says it has
    none (and why, when every walk was skipped in processing): what a selection that matched
    nothing names, so a misspelt floor is plain."""
    cat = processed_catalog(store)  # read once: the walks that processed and those skipped
    ok = cat[cat["status"] == "ok"]
    if not len(ok):
        skipped = cat[cat["status"] == "skipped"]
        if len(skipped):  # processed, and every one refused: say why, not to process them
            first = skipped.iloc[0]
            return (f"the store has no walk that processed: {len(skipped)} skipped (the first, "
                    f"{first['trace_id']}: {first['reason']})")
        return "the store has no processed walks (indoormap process --store STORE)"
    parts = []
    for site, walks in ok.groupby("site", sort=True):
        counts = walks["floor"].value_counts().sort_index()
        parts.append(f"site {site} floors " + ", ".join(f"{f} ({n})" for f, n in counts.items()))
    return "the store has processed walks of " + "; ".join(parts)
