"""Validation of a floor's map bundle: is the map good enough, and where must the surveyor walk again?

:func:`validate_bundle` checks a bundle (and, with its survey store, the data it was built from)
and returns a :class:`ValidationResult`: JSON-able ``metrics``, ``findings`` (what failed and
where), a ``verdict`` (``"pass"`` when no threshold fails) and the arrays the figures draw
(:mod:`mapping.report_html` writes the report; ``indoormap validate`` is the command).

Sections (``docs/validation.md`` explains each figure and threshold):

1. **coverage**: share of the reachable area within 1 / 2 / 5 m (straight line, as the bundle's
   own metric) of survey samples; walking distance (through reachable cells only) to the
   nearest sample; *unsupported regions* (connected reachable areas farther than
   ``unsupported_distance_m`` walking distance from any sample); walks per cell and per zone
   (square tiles of ``zone_m``; corridors are not known for arbitrary plans).
2. **consistency**: the field of every walk levelled with the bundle's own per-session
   residuals (table ``levelling``), averaged per (walk, report cell); each walk's median offset
   from the other walks in the cells they share, and per cell the spread between walks after
   those offsets are removed (where overlapping walks disagree).
3. **heldout**: :func:`mapping.holdout.leave_one_walk_out` (the one implementation, also behind
   ``benchmarks/map_accuracy.py``) with the bundle's raster and levelling parameters and
   :func:`mapping.holdout.default_pipelines`; per held-out walk the median residual (a walk
   offset) and shape RMSE; per report cell the RMS of shape residuals (error maps); CDFs. The
   heading-offset layer is held out the same way (its own loop: an angle layer from steps).
4. **predicted**: per cell the magnetic *resolution*
   ``1 / sqrt(sum_k |grad f_k|^2 / sigma_k^2)`` (m) over strength, horizontal and vertical,
   ``sigma_k`` being the held-out shape RMSE of that layer (map and observation noise together):
   the distance over which the field changes by one noise level. Large = magnetically flat.
   Radio: a Cramer-Rao style bound over the fingerprint map (section 7).
5. **calibration**: per walk the magnetometer calibration decision; per session the levelling
   residual; per device the RSSI ``(k, b)`` when the bundle or the radio modules provide them.
6. **data_quality**: bad / skipped lines per walk (store catalog), flagged legs by reason,
   waypoints outside the reachable area, walks skipped by processing and why.
7. **radio**: held-out Wi-Fi/BLE positioning errors (rebuilt per fold from the training walks),
   the site floor model's cross-validated accuracy, a Cramer-Rao style bound per cell
   (:mod:`mapping.radio_validation`).

Thresholds: :data:`DEFAULT_THRESHOLDS` (documented in :data:`THRESHOLD_DOCS`), overridden by a
JSON file (:func:`load_thresholds`); ``None`` disables a check.
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from survey.regular_files import read_regular
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from localize.bundle import Grid, MapBundle, load_bundle
from survey.errors import IndoormapError
from survey.field_features import circular_median_deg, wrap_deg
from survey.publish import file_sha256
from survey.trace_format import bad_lines_summary

from . import holdout
from .build import BuildParams, field_left_out, heading_raster_for
from .grid import distance_to_reachable_m
from .interpolate import INTERPOLATORS, CellStats, RasterParams, cell_stats, walk_cell_means
from .levelling import LevellingParams, apply_session_residuals

if TYPE_CHECKING:  # an annotation only
    from survey.store import SurveyStore

_T = TypeVar("_T")


class ValidationError(IndoormapError, ValueError):
    """Validation cannot run on these inputs (bad thresholds file, unusable bundle)."""


# ----------------------------------------------------------------------------------------------
# thresholds

#: Default thresholds; a check fails when its value is on the wrong side. ``None`` = not checked.
DEFAULT_THRESHOLDS: dict[str, float | list | None] = {
    "coverage_within_2m_min": 0.80,
    "coverage_within_5m_min": 0.95,
    "unsupported_distance_m": 3.0,
    "unsupported_region_max_m2": 6.0,
    "walk_offset_max_ut": 4.0,
    "walk_min_shared_cells": 10,
    "disagreement_ut": 3.0,
    "disagreeing_cells_max_share": 0.15,
    "heldout_strength_shape_rmse_max_ut": 4.0,
    "heldout_skill_min": 0.0,
    "heading_offset_shape_rmse_max_deg": 20.0,
    "magnetic_resolution_m": 2.0,
    "magnetic_flat_share_max": None,
    "levelling_residual_max_ut": 15.0,
    "not_calibrated_walks_max": 0,
    "bad_line_share_max": 0.01,
    "leg_flags_fail": ["waypoint", "scale", "speed", "step_length", "heading", "no_steps"],
    "leg_min_length_m": 2.0,
    "waypoint_outside_tolerance_m": 1.0,
    "waypoints_outside_max": 0,
    "skipped_walks_max": 0,
    "zone_min_walks": None,
    "radio_median_error_max_m": None,
    "radio_floor_accuracy_min": None,
}

THRESHOLD_DOCS: dict[str, str] = {
    "coverage_within_2m_min": "share of reachable cells within 2 m (straight line) of a sample",
    "coverage_within_5m_min": "share of reachable cells within 5 m (straight line) of a sample",
    "unsupported_distance_m": "a reachable cell farther than this walking distance from every "
                              "sample is unsupported (the map's own reach is 3 m)",
    "unsupported_region_max_m2": "largest connected unsupported region allowed (m2); every "
                                 "larger one is a finding with its place",
    "walk_offset_max_ut": "largest |median offset| of a walk from the other walks in the cells "
                          "they share, after levelling (strength or vertical, uT)",
    "walk_min_shared_cells": "report cells a walk must share with other walks before its "
                             "offset is judged",
    "disagreement_ut": "a report cell disagrees when the walks crossing it spread more than "
                       "this (strength, uT, SD after each walk's offset is removed)",
    "disagreeing_cells_max_share": "largest share of multi-walk cells that disagree",
    "heldout_strength_shape_rmse_max_ut": "largest leave-one-walk-out shape RMSE of strength "
                                          "(indoormap default pipeline, uT)",
    "heldout_skill_min": "smallest skill (1 - shape RMSE / constant map's) of strength",
    "heading_offset_shape_rmse_max_deg": "largest held-out shape RMSE of the heading-offset "
                                         "layer (deg)",
    "magnetic_resolution_m": "a mapped cell is magnetically flat when the field changes by "
                             "less than one noise level over this distance",
    "magnetic_flat_share_max": "largest share of mapped cells that are magnetically flat (None: "
                               "reported, not checked; a one-sample bound is pessimistic for a "
                               "localizer that integrates along the track)",
    "levelling_residual_max_ut": "largest per-session levelling residual |r| (uT): a session "
                                 "whose calibration was far off",
    "not_calibrated_walks_max": "walks with calibration decision 'not-calibrated' allowed",
    "bad_line_share_max": "largest share of bad lines in a walk's trace",
    "leg_flags_fail": "leg flags (survey.positions.FLAGS) that fail a walk; other flags are "
                      "warnings",
    "leg_min_length_m": "legs shorter than this are not failed for speed, step_length or scale "
                        "(click timing noise dominates: 0.3 s on a 0.6 m leg is 'speed')",
    "waypoint_outside_tolerance_m": "a waypoint farther than this from the reachable area is "
                                    "outside",
    "waypoints_outside_max": "waypoints outside the reachable area allowed",
    "skipped_walks_max": "walks that processing skipped allowed",
    "zone_min_walks": "fewest walks a zone (square of zone_m) with reachable area must have "
                      "(None: reported, not checked)",
    "radio_median_error_max_m": "largest held-out median radio positioning error (m)",
    "radio_floor_accuracy_min": "smallest held-out radio floor accuracy",
}


#: Largest thresholds file read (bytes): a JSON object of a dozen numbers.
MAX_THRESHOLDS_BYTES = 2**20


def load_thresholds(path: str | Path | None = None, overrides: dict | None = None) -> dict:
    """Default thresholds updated from a JSON object file (and/or a dict); unknown keys are an
    error (a typo must not silently disable a check)."""
    th = dict(DEFAULT_THRESHOLDS)
    extra: dict = {}
    if path is not None:
        try:
            extra = json.loads(read_regular(path, MAX_THRESHOLDS_BYTES).decode("utf-8"))
        except (OSError, ValueError) as err:
            raise ValidationError(f"{path}: not a readable JSON file ({err})") from err
        if not isinstance(extra, dict):
            raise ValidationError(f"{path}: thresholds must be a JSON object")
    extra = {**extra, **(overrides or {})}
    unknown = sorted(set(extra) - set(th))
    if unknown:
        raise ValidationError(f"unknown threshold(s) {unknown}; known: {sorted(th)}")
    for k, v in extra.items():
        if isinstance(DEFAULT_THRESHOLDS[k], list):
            if not (isinstance(v, list) and all(isinstance(s, str) for s in v)):
                raise ValidationError(f"threshold {k} must be a list of flag names")
        elif v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                                or not math.isfinite(v)):
            raise ValidationError(f"threshold {k} must be a finite number or null, got {v!r}")
        elif v is not None:
            low, high = _THRESHOLD_RANGES.get(k, (0.0, math.inf))
            if not (low <= v <= high) or (k in _POSITIVE_THRESHOLDS and v == 0):
                raise ValidationError(
                    f"threshold {k} must be {'above' if k in _POSITIVE_THRESHOLDS else 'at least'}"
                    f" {low:g}" + (f" and at most {high:g}" if math.isfinite(high) else "")
                    + f", got {v!r}")
        th[k] = v
    return th


#: Ranges of the numeric thresholds other than [0, inf): shares and accuracies in [0, 1]; a
#: skill may be negative (worse than the constant map).
_THRESHOLD_RANGES = {
    **{k: (0.0, 1.0) for k in ("coverage_within_2m_min", "coverage_within_5m_min",
                               "disagreeing_cells_max_share", "magnetic_flat_share_max",
                               "bad_line_share_max", "radio_floor_accuracy_min")},
    "heldout_skill_min": (-math.inf, 1.0),
}
#: Distances that must be above zero (a grid of them is drawn, or they divide).
_POSITIVE_THRESHOLDS = frozenset({"magnetic_resolution_m", "unsupported_distance_m"})


# ----------------------------------------------------------------------------------------------
# parameters and results

@dataclass(frozen=True)
class ValidateParams:
    """How much work validation does (the held-out part is the slow one).

    ``holdout_subsample`` and ``holdout_levelling_folds`` are passed to
    :func:`mapping.holdout.leave_one_walk_out` (its defaults, 5 and 10, are what
    ``benchmarks/map_accuracy.py`` uses, so the figures are the same); ``holdout_baseline``
    keeps the linear/time-linear baseline pipeline in the comparison (the slowest pipeline on
    large floors; without it the common support, hence the figures, differ from the benchmark's).
    """

    holdout: bool = True
    holdout_layers: tuple[str, ...] = ("strength", "vertical")
    holdout_subsample: int = 5
    holdout_levelling_folds: int = 10
    holdout_baseline: bool = True
    heading_holdout: bool = True
    radio: bool = True
    report_cell_m: float = 1.0
    zone_m: float = 5.0
    walks_radius_m: float = 1.0
    max_listed: int = 15  # findings of one check listed one by one; the rest are summarised

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


@dataclass
class Finding:
    """One result of a check. ``severity``: ``fail`` (a threshold failed), ``warn``, ``info``."""

    check: str
    severity: str
    message: str
    section: str
    walk: str | None = None
    where: dict | None = None
    value: float | None = None
    threshold: float | list | None = None

    def to_dict(self) -> dict:
        return _jsonable(asdict(self))


@dataclass
class ValidationResult:
    """What :func:`validate_bundle` found.

    ``metrics`` is JSON-able (written as ``metrics.json``); ``arrays`` holds rasters and point
    sets for the figures (not written as JSON); ``grids`` names the grid of each raster."""

    metrics: dict
    findings: list[Finding]
    thresholds: dict
    arrays: dict = field(default_factory=dict)
    bundle: MapBundle | None = None
    report_grid: Grid | None = None
    floor_dir: Path | None = None

    @property
    def verdict(self) -> str:
        return "fail" if any(f.severity == "fail" for f in self.findings) else "pass"

    @property
    def failed(self) -> list[Finding]:
        return [f for f in self.findings if f.severity == "fail"]

    def verdict_text(self) -> str:
        """The verdict as the CLI and the report say it: ``"PASS"``, or ``"PASS (3 of 14
        checks ran; 11 not run: their input was missing)"`` when checks could not run (no
        survey store given), so that a bundle checked alone does not read as validated;
        ``"FAIL"`` likewise."""
        rows = [c for c in self.metrics.get("checks", []) if c["status"] != "off"]
        not_run = sum(c["status"] == "not run" for c in rows)
        text = self.verdict.upper()
        if not_run:
            text += (f" ({len(rows) - not_run} of {len(rows)} checks ran; {not_run} not run: "
                     "their input was missing)")
        return text

    def __repr__(self) -> str:
        """A summary: the verdict, the floor and the failed checks (the full repr, with every
        raster and point set in ``arrays``, ran to some 44,000 lines in a notebook)."""
        floor = None if self.bundle is None else self.bundle.floor_id
        failed = sorted({f.check for f in self.failed})
        return (f"ValidationResult({self.verdict_text()!r}, floor={floor!r}, "
                f"findings={len(self.findings)}, failed={failed}, "
                f"arrays={sorted(self.arrays)})")

    def to_json(self) -> dict:
        return _jsonable({"verdict": self.verdict, "thresholds": self.thresholds,
                          "findings": [f.to_dict() for f in self.findings], **self.metrics})


def _jsonable(obj):
    """Plain JSON types; NaN/inf become None."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, Path):
        return str(obj)
    return obj


# ----------------------------------------------------------------------------------------------
# small raster helpers

def report_grid_of(grid: Grid, cell_m: float) -> Grid:
    """A coarser grid over the bundle grid's extent (cells of ``cell_m``, at least the
    bundle's)."""
    cell = max(float(cell_m), grid.cell_m)
    return Grid(grid.x0_m, grid.y0_m, cell, int(math.ceil(grid.width * grid.cell_m / cell)),
                int(math.ceil(grid.height * grid.cell_m / cell)))


def _report_mask(grid: Grid, mask: NDArray[np.bool_], rgrid: Grid) -> NDArray[np.bool_]:
    """Report cells holding any reachable bundle cell."""
    xc, yc = grid.cell_centers()
    xx, yy = np.meshgrid(xc, yc)
    r, c, inside = rgrid.cell_of(xx[mask], yy[mask])
    out = np.zeros(rgrid.shape, dtype=bool)
    out[r[inside], c[inside]] = True
    return out


def _cell_reduce(g: Grid, x: NDArray, y: NDArray, v: NDArray, *, rms: bool = False,
                 min_count: int = 1) -> tuple[NDArray, NDArray]:
    """Per-cell mean (or RMS) of values at points and the count, NaN where fewer than
    ``min_count``."""
    r, c, inside = g.cell_of(x, y)
    ok = inside & np.isfinite(v)
    flat = (r * g.width + c)[ok]
    vv = np.asarray(v, dtype=np.float64)[ok]
    n = np.bincount(flat, minlength=g.width * g.height).reshape(g.shape)
    s = np.bincount(flat, weights=vv * vv if rms else vv,
                    minlength=g.width * g.height).reshape(g.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        m = s / n
    if rms:
        m = np.sqrt(m)
    m[n < min_count] = np.nan
    return m, n


def walking_distance(grid: Grid, mask: NDArray[np.bool_], support: NDArray[np.bool_]
                     ) -> NDArray[np.float64]:
    """Distance (m) from every reachable cell to the nearest support cell, moving through
    reachable cells only (8-neighbour steps); inf where unreachable, NaN off the mask."""
    h, w = grid.shape
    idx = -np.ones(grid.shape, dtype=np.int64)
    idx[mask] = np.arange(int(mask.sum()))
    rows, cols, weights = [], [], []
    for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)):  # cell (i, j) to (i + di, j + dj)
        ja, jb = (slice(0, w - dj), slice(dj, w)) if dj >= 0 else (slice(-dj, w),
                                                                    slice(0, w + dj))
        a = idx[0:h - di, ja]
        b = idx[di:h, jb]
        ok = (a >= 0) & (b >= 0)
        rows.append(a[ok])
        cols.append(b[ok])
        weights.append(np.full(int(ok.sum()), grid.cell_m * math.hypot(di, dj)))
    n = int(mask.sum())
    out = np.full(grid.shape, np.nan)
    src = idx[support & mask]
    if n == 0:
        return out
    if not len(src):
        out[mask] = np.inf
        return out
    graph = sparse.csr_matrix((np.concatenate(weights), (np.concatenate(rows),
                                                          np.concatenate(cols))), shape=(n, n))
    dist = csgraph.dijkstra(graph, directed=False, indices=src, min_only=True)
    out[mask] = dist
    return out


def _regions(grid: Grid, sel: NDArray[np.bool_], min_area_m2: float = 0.0) -> tuple[
        NDArray[np.int64], list[dict]]:
    """Connected (8-neighbour) regions of ``sel`` with area, centroid and bounding box (m),
    largest first."""
    lab, n = ndimage.label(sel, structure=np.ones((3, 3)))
    if n == 0:
        return lab, []
    cell_a = grid.cell_m ** 2
    counts = np.bincount(lab.ravel(), minlength=n + 1)
    xc, yc = grid.cell_centers()
    rr, cc = np.nonzero(lab)
    ll = lab[rr, cc]
    sx = np.bincount(ll, weights=xc[cc], minlength=n + 1)
    sy = np.bincount(ll, weights=yc[rr], minlength=n + 1)
    out = []
    for k, sl in enumerate(ndimage.find_objects(lab), start=1):
        area = counts[k] * cell_a
        if sl is None or area < min_area_m2:
            continue
        r0, r1, c0, c1 = sl[0].start, sl[0].stop, sl[1].start, sl[1].stop
        # the point said and marked: of the region's cells farthest from its edge, the one
        # nearest its centroid (a centroid can lie outside an L-shaped region, and the cell
        # nearest it on the region's edge, against a wall)
        cx, cy = sx[k] / counts[k], sy[k] / counts[k]
        inside = lab[sl] == k
        depth = ndimage.distance_transform_edt(np.pad(inside, 1))[1:-1, 1:-1]
        rr_k, cc_k = np.nonzero(inside & (depth >= depth.max()))
        px, py = xc[cc_k + c0], yc[rr_k + r0]
        i = int(np.argmin((px - cx) ** 2 + (py - cy) ** 2))
        out.append({"label": k, "area_m2": float(area),
                    "x_m": float(px[i]), "y_m": float(py[i]),
                    "bbox_m": [grid.x0_m + c0 * grid.cell_m, grid.y0_m + r0 * grid.cell_m,
                               grid.x0_m + c1 * grid.cell_m, grid.y0_m + r1 * grid.cell_m]})
    out.sort(key=lambda d: -d["area_m2"])
    return lab, out


def _fmt_xy(d: dict) -> str:
    return f"({d['x_m']:.1f}, {d['y_m']:.1f}) m"


# ----------------------------------------------------------------------------------------------
# inputs

@dataclass
class FloorData:
    """What the store holds for the bundle's floor."""

    floor: str
    site: str | None
    samples: pd.DataFrame
    steps: pd.DataFrame
    legs: pd.DataFrame
    pcat: pd.DataFrame  # processed catalog rows of the floor (ok and skipped)
    catalog: pd.DataFrame  # store catalog rows of the floor
    waypoints: pd.DataFrame
    #: walks of the floor in the store, processed ok or not processed, that are not among the
    #: bundle's source walks (``build --exclude``, or ingested after the build): left out of
    #: every table above
    not_in_bundle: tuple[str, ...] = ()


def load_floor_data(store: SurveyStore | str | Path, bundle: MapBundle) -> FloorData:
    """Processed tables of the bundle's floor from a survey store (samples with time-linear
    positions too, as :func:`mapping.holdout.floor_samples_with_baseline_positions` gives):
    the walks of the bundle's site (that of its source walks found in the store, else its
    ``site_id``) on its floor. When some of the bundle's source walks are in the store, the
    store's other walks processed ok or not processed (left out by ``build --exclude``, or
    ingested later) are left out too, so the report scores the map on the walks it was built
    from; walks that processing skipped or failed stay listed.

    Raises
    ------
    ValidationError
        The store holds no walk of that site and floor (another site's store).
    """
    from survey.process_store import processed_catalog, processed_table
    from survey.store import SurveyStore

    store = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
    m = bundle.manifest
    floor = m.get("floor_name") or m.get("floor_id")
    cat = store.catalog()
    walks = {w["trace_id"] for w in m.get("build", {}).get("source_walks", [])}
    mine = cat[cat["trace_id"].isin(walks)]
    # the site of the bundle's own walks in the store, else the bundle's site: never every
    # site's walks of a floor that happens to share the name
    site = str(mine["site"].iloc[0]) if len(mine) else str(bundle.site_id or "")
    fcat = cat[(cat["floor"] == floor) & (cat["site"] == site)]
    if not len(fcat):
        sites = sorted(set(cat.loc[cat["floor"] == floor, "site"].astype(str)))
        raise ValidationError(
            f"{store.root}: the store holds no walk of {bundle.path}'s site {site or '(none)'}, "
            f"floor {floor}" + (f" (its {floor} walks are of site {', '.join(sites)})"
                                if sites else "") + ": validate the bundle with the store "
            "it was built from")
    pcat = processed_catalog(store)
    pcat = pcat[(pcat["floor"] == floor) & (pcat["site"] == site)]
    # a build processes every walk it reads: a walk of the floor processed ok, or never
    # processed, that is not among the source walks was not an input (excluded, or ingested
    # later); walks processing skipped or failed stay, as the build met them too
    not_done = set(pcat.loc[pcat["status"] != "ok", "trace_id"])
    not_in_bundle = sorted(set(fcat["trace_id"]) - walks - not_done) if len(mine) else []

    def of_bundle(table: pd.DataFrame) -> pd.DataFrame:
        if not not_in_bundle:
            return table
        return table[~table["trace_id"].isin(not_in_bundle)].reset_index(drop=True)

    samples = holdout.floor_samples_with_baseline_positions(store, floor, site)
    if left_out := field_left_out(m.get("metrics", {})):  # out of the map it measures too
        samples = samples[~samples["trace_id"].isin(left_out)]
    steps = processed_table(store, "steps", site=site, floor=floor)
    legs = processed_table(store, "legs", site=site, floor=floor)
    waypoints = store.table("waypoints", site=site, floor=floor)
    return FloorData(floor, site, of_bundle(samples), of_bundle(steps), of_bundle(legs),
                     of_bundle(pcat.reset_index(drop=True)),
                     of_bundle(fcat.reset_index(drop=True)), of_bundle(waypoints),
                     tuple(not_in_bundle))


def floor_dir_problem(floor_dir: Path, manifest: dict) -> str | None:
    """Why a floor folder given for the figures (``--floor-dir``) cannot be the floor of the
    bundle whose ``manifest`` is given, else None: it holds neither ``floor_image.png`` nor
    ``floor_info.json``, or a ``geojson_map.json`` other than the one the bundle was built on
    (the build recorded its sha256; a bundle built on a DXF drawing is not compared)."""
    if not any((floor_dir / n).exists() for n in ("floor_image.png", "floor_info.json")):
        return (f"--floor-dir {floor_dir} holds neither floor_image.png nor floor_info.json: "
                "the figures have no floor image")
    built_on = {f.get("sha256") for f in manifest.get("build", {}).get("floor_plan", [])
                if isinstance(f, dict) and f.get("file") == "geojson_map.json"}
    plan = floor_dir / "geojson_map.json"
    if built_on and plan.is_file() and file_sha256(plan) not in built_on:
        return (f"--floor-dir {floor_dir}: its geojson_map.json is not the plan the bundle "
                f"was built on (floor {manifest.get('floor_name', '')!r}): the figures are "
                "drawn over another floor's image")
    return None


def floor_dir_of(fd: FloorData | None) -> Path | None:
    """The floor folder the walks were ingested from, when it still exists and holds a
    plan: the nearest folder above a walk's source holding one, up to three levels
    (``<floor>/path_data_files/<trace>``, or a walk-line log's
    ``<floor>/<survey>/logs/<walk>.csv``)."""
    if fd is None or not len(fd.catalog):
        return None
    for src in fd.catalog["source_path"]:
        for cand in Path(str(src)).parents[:3]:
            if (cand / "geojson_map.json").exists() or (cand / "floor_image.png").exists():
                return cand
    return None


def _bundle_raster_params(bundle: MapBundle) -> tuple[RasterParams, RasterParams,
                                                      LevellingParams]:
    """The raster (with the bundle's chosen bandwidth), heading raster and levelling
    parameters the bundle was built with."""
    m = bundle.manifest
    p = m.get("build", {}).get("params", {})
    raster = RasterParams(**p.get("raster", {}))
    heading = RasterParams(**p.get("heading_raster", asdict(BuildParams().heading_raster)))
    metrics = m.get("metrics", {})
    bw = metrics.get("bandwidth_m")
    if bw is not None:
        chosen = {"bandwidth_m": float(bw)}
        if metrics.get("interpolator") in INTERPOLATORS:
            chosen["method"] = metrics["interpolator"]
        for name in ("prior_walks", "slope_ridge", "curvature_ridge"):
            if metrics.get(name) is not None:
                chosen[name] = float(metrics[name])
        raster = replace(raster, **chosen)
        if p.get("auto_bandwidth", True) and raster.kernel_based:
            heading = heading_raster_for(heading, bw)
    lev = LevellingParams(**p.get("levelling", {}))
    return raster, heading, lev


# ----------------------------------------------------------------------------------------------
# 1. coverage

def coverage_section(bundle: MapBundle, fd: FloorData | None, th: dict, params: ValidateParams,
                     findings: list[Finding], arrays: dict) -> dict:
    from .build import coverage

    g, mask = bundle.grid, np.asarray(bundle.mask, dtype=bool)
    reach_m2 = float(mask.sum() * g.cell_m ** 2)
    out: dict = {"reachable_area_m2": reach_m2}
    strength = np.asarray(bundle.layers.get("strength")) if "strength" in bundle.layers \
        else None
    if strength is not None:
        out["mapped_share"] = float(np.isfinite(strength[mask]).mean()) if mask.any() else 0.0
    if fd is None:
        cov = bundle.manifest.get("metrics", {}).get("coverage", {})
        out["euclidean"] = cov
        out["source"] = "bundle manifest (no store)"
    else:
        s = fd.samples
        x, y = s["x_m"].to_numpy(), s["y_m"].to_numpy()
        r, c, inside = g.cell_of(x, y)
        support = np.zeros(g.shape, dtype=bool)
        support[r[inside], c[inside]] = True
        out["euclidean"] = coverage(g, mask, support)
        out["source"] = "store samples"
        support &= mask
        geo = walking_distance(g, mask, support)
        arrays["walking_distance_m"] = geo
        gm = geo[mask]
        out["walking"] = {f"within_{d:g}m": float((gm <= d).mean()) if len(gm) else 0.0
                          for d in (1.0, 2.0, 5.0)}
        dlim = float(th.get("unsupported_distance_m") or 3.0)
        unsup = mask & ~(geo <= dlim)
        lab, regions = _regions(g, unsup)
        for reg in regions:
            sel = lab == reg["label"]
            far = geo[sel]
            reg["max_walking_distance_m"] = float(np.max(far)) if np.isfinite(far).all() \
                else None
            reg["isolated"] = bool(~np.isfinite(far).all())
        arrays["unsupported_labels"] = lab
        out["unsupported_distance_m"] = dlim
        out["unsupported_area_m2"] = float(unsup.sum() * g.cell_m ** 2)
        out["unsupported_share"] = float(unsup.sum() / max(int(mask.sum()), 1))
        out["unsupported_regions"] = regions[:50]
        # walks per cell: distinct walks with a sample within walks_radius_m
        rad = max(1, int(round(params.walks_radius_m / g.cell_m)))
        yy, xx = np.mgrid[-rad:rad + 1, -rad:rad + 1]
        disk = (xx * xx + yy * yy) <= rad * rad
        count = np.zeros(g.shape, dtype=np.int32)
        codes, walk_ids = pd.factorize(s["trace_id"])
        for k in range(len(walk_ids)):
            sel = inside & (codes == k)
            if not sel.any():
                continue
            rr, cc = r[sel], c[sel]
            r0, r1 = max(rr.min() - rad, 0), min(rr.max() + rad + 1, g.height)
            c0, c1 = max(cc.min() - rad, 0), min(cc.max() + rad + 1, g.width)
            sub = np.zeros((r1 - r0, c1 - c0), dtype=bool)
            sub[rr - r0, cc - c0] = True
            count[r0:r1, c0:c1] += ndimage.binary_dilation(sub, structure=disk)
        count = np.where(mask, count, 0)
        arrays["walks_per_cell"] = count
        step = max(1, len(s) // 40000)
        arrays["tracks"] = {str(walk_ids[k]): (x[codes == k][::step], y[codes == k][::step])
                            for k in range(len(walk_ids))}
        cm = count[mask]
        out["walks_per_cell"] = {"radius_m": params.walks_radius_m,
                                 "share_0": float((cm == 0).mean()) if len(cm) else 0.0,
                                 "share_1": float((cm == 1).mean()) if len(cm) else 0.0,
                                 "share_2_plus": float((cm >= 2).mean()) if len(cm) else 0.0,
                                 "median_where_walked": float(np.median(cm[cm > 0]))
                                 if (cm > 0).any() else 0.0}
        out["zones"] = _zones(g, mask, geo, s, params.zone_m)
    # checks
    for key, d in (("coverage_within_2m_min", "within_2m"), ("coverage_within_5m_min",
                                                              "within_5m")):
        t = th.get(key)
        v = out["euclidean"].get(d)
        if t is not None and v is not None and v < t:
            findings.append(Finding(key, "fail", f"only {100 * v:.0f} % of the reachable area is "
                                    f"within {d[7:-1]} m of a survey sample (needs "
                                    f"{100 * t:.0f} %)", "coverage", value=v, threshold=t))
    t = th.get("unsupported_region_max_m2")
    if fd is not None and t is not None:
        big = [r for r in out["unsupported_regions"] if r["area_m2"] > t]
        for reg in big[:params.max_listed]:
            findings.append(Finding(
                "unsupported_region", "fail",
                f"unsupported area of {reg['area_m2']:.0f} m2 around {_fmt_xy(reg)} (bbox "
                f"{', '.join(f'{v:.0f}' for v in reg['bbox_m'])} m): no sample within "
                f"{out['unsupported_distance_m']:g} m walking distance"
                + (" (not connected to any surveyed area)" if reg["isolated"] else "")
                + "; walk it", "coverage", where={k: reg[k] for k in ("x_m", "y_m", "bbox_m",
                                                                      "area_m2")},
                value=reg["area_m2"], threshold=t))
        if len(big) > params.max_listed:
            findings.append(Finding("unsupported_region", "fail",
                                    f"... and {len(big) - params.max_listed} more unsupported "
                                    f"regions larger than {t:g} m2", "coverage",
                                    value=len(big), threshold=t))
    if fd is not None:
        t = th.get("zone_min_walks")
        out["zones_single_walk"] = sum(1 for z in out["zones"] if z["walks"] == 1)
        out["zones_no_walk"] = sum(1 for z in out["zones"] if z["walks"] == 0)
        thin = [z for z in out["zones"] if t is not None and z["walks"] < t
                and z["reachable_m2"] >= 0.25 * params.zone_m ** 2]
        for z in thin[:params.max_listed]:
            findings.append(Finding(
                "zone_walks", "fail",
                f"zone around {_fmt_xy(z)} has {z['walks']} walk(s)"
                + (": nothing to cross-check it against" if z["walks"] == 1 else ""),
                "coverage", where={k: z[k] for k in ("x_m", "y_m", "bbox_m")},
                value=z["walks"], threshold=t))
    return out


def _zones(g: Grid, mask: NDArray, geo: NDArray, s: pd.DataFrame, zone_m: float) -> list[dict]:
    zg = report_grid_of(g, zone_m)
    xc, yc = g.cell_centers()
    xx, yy = np.meshgrid(xc, yc)
    zr, zc, _ = zg.cell_of(xx, yy)
    zone_of_cell = zr * zg.width + zc
    n_reach = np.bincount(zone_of_cell[mask], minlength=zg.width * zg.height)
    n_close = np.bincount(zone_of_cell[mask & (geo <= 2.0)], minlength=zg.width * zg.height)
    r, c, inside = zg.cell_of(s["x_m"].to_numpy(), s["y_m"].to_numpy())
    pairs = pd.DataFrame({"zone": (r * zg.width + c)[inside],
                          "walk": s["trace_id"].to_numpy()[inside]}).drop_duplicates()
    walks = pairs.groupby("zone")["walk"].nunique()
    out = []
    for z in np.flatnonzero(n_reach):
        zr_, zc_ = divmod(int(z), zg.width)
        x0, y0 = zg.x0_m + zc_ * zg.cell_m, zg.y0_m + zr_ * zg.cell_m
        out.append({"zone": int(z), "x_m": x0 + zg.cell_m / 2, "y_m": y0 + zg.cell_m / 2,
                    "bbox_m": [x0, y0, x0 + zg.cell_m, y0 + zg.cell_m],
                    "reachable_m2": float(n_reach[z] * g.cell_m ** 2),
                    "within_2m_share": float(n_close[z] / n_reach[z]),
                    "walks": int(walks.get(int(z), 0))})
    out.sort(key=lambda d: (d["walks"], -d["reachable_m2"]))
    return out


# ----------------------------------------------------------------------------------------------
# 2. consistency

def consistency_section(bundle: MapBundle, fd: FloorData, th: dict, params: ValidateParams,
                        findings: list[Finding], arrays: dict, rgrid: Grid) -> dict:
    out: dict = {}
    if bundle.has_table("levelling"):
        lev = bundle.table("levelling").to_pandas()
        lev["session"] = lev["session"].astype(str)
        residuals = lev.set_index("session")
        r = residuals[["r_x_ut", "r_y_ut", "r_z_ut"]].to_numpy(np.float64)
        out["levelling"] = [{"session": sid, "r_x_ut": float(a), "r_y_ut": float(b),
                             "r_z_ut": float(c), "norm_ut": float(math.sqrt(a * a + b * b + c * c)),
                             "n_pairs": int(row["n_pairs"]), "n_samples": int(row["n_samples"])}
                            for sid, (a, b, c), (_, row) in zip(residuals.index, r,
                                                                residuals.iterrows())]
    else:
        residuals = pd.DataFrame(columns=["r_x_ut", "r_y_ut", "r_z_ut"])
        out["levelling"] = []
    t = th.get("levelling_residual_max_ut")
    if t is not None:
        for row in out["levelling"]:
            if row["norm_ut"] > t:
                findings.append(Finding(
                    "levelling_residual", "fail",
                    f"calibration session {row['session']}: levelling had to remove "
                    f"{row['norm_ut']:.1f} uT (threshold {t:g}): its phone calibration was far "
                    "off", "consistency", value=row["norm_ut"], threshold=t))
    s = fd.samples
    field_enu = apply_session_residuals(s, residuals) if len(residuals) else \
        s[["mag_east_ut", "mag_north_ut", "mag_up_ut"]].to_numpy(np.float64)
    e, n, u = field_enu.T
    values = {"strength": np.sqrt(e * e + n * n + u * u), "vertical": u,
              "horizontal": np.hypot(e, n)}
    codes, walk_ids = pd.factorize(s["trace_id"])
    x, y = s["x_m"].to_numpy(), s["y_m"].to_numpy()
    size = rgrid.width * rgrid.height
    per_walk: dict[str, dict] = {str(w): {} for w in walk_ids}
    thr = th.get("disagreement_ut")
    for layer, v in values.items():
        w, cell, mean = walk_cell_means(rgrid, x, y, v, codes)
        n_c = np.bincount(cell, minlength=size).astype(np.float64)
        s_c = np.bincount(cell, weights=mean, minlength=size)
        shared = n_c[cell] >= 2
        others = (s_c[cell] - mean) / np.maximum(n_c[cell] - 1, 1)
        d = np.where(shared, mean - others, np.nan)
        offs = pd.Series(d).groupby(w).median()
        cnt = pd.Series(shared.astype(int)).groupby(w).sum()
        for k, wid in enumerate(walk_ids):
            per_walk[str(wid)][layer] = float(offs.get(k, np.nan))
            per_walk[str(wid)]["shared_cells"] = int(cnt.get(k, 0))
        adj = mean - offs.reindex(w).fillna(0.0).to_numpy()
        s1 = np.bincount(cell, weights=adj, minlength=size)
        s2 = np.bincount(cell, weights=adj * adj, minlength=size)
        with np.errstate(invalid="ignore", divide="ignore"):
            var = (s2 - s1 * s1 / n_c) / (n_c - 1)
        sd = np.where(n_c >= 2, np.sqrt(np.maximum(var, 0)), np.nan).reshape(rgrid.shape)
        arrays[f"disagreement_{layer}"] = sd
        fin = sd[np.isfinite(sd)]
        out[f"disagreement_{layer}"] = {
            "multi_walk_cells": int(fin.size),
            "median_sd_ut": float(np.median(fin)) if fin.size else None,
            "p90_sd_ut": float(np.percentile(fin, 90)) if fin.size else None,
            "share_above": float((fin > thr).mean()) if fin.size and thr is not None else None}
        if layer == "strength":
            # which walks disagree most in the worst cells (for the findings)
            dev = np.abs(adj - (s1[cell] - adj) / np.maximum(n_c[cell] - 1, 1))
            dev = np.where(n_c[cell] >= 2, dev, np.nan)
            arrays["_strength_cell_walk_dev"] = (cell, w, dev)
    out["walk_offsets_ut"] = per_walk
    out["report_cell_m"] = rgrid.cell_m
    t = th.get("walk_offset_max_ut")
    min_cells = int(th.get("walk_min_shared_cells") or 1)
    for rec in per_walk.values():
        rec["offset_ut"] = max((abs(rec[la]) for la in ("strength", "vertical")
                                if np.isfinite(rec.get(la, np.nan))), default=None) \
            if rec.get("shared_cells", 0) >= min_cells else None
    if t is not None:
        bad = sorted(((w, r) for w, r in per_walk.items()
                      if r["offset_ut"] is not None and r["offset_ut"] > t),
                     key=lambda wr: -wr[1]["offset_ut"])
        for w, r in bad[:params.max_listed]:
            findings.append(Finding(
                "walk_offset", "fail",
                f"walk {w} is offset from the walks it overlaps after levelling (median "
                f"strength {r['strength']:+.1f} uT, vertical {r['vertical']:+.1f} uT over "
                f"{r['shared_cells']} shared cells; threshold {t:g} uT): check its "
                "calibration or drop it", "consistency", walk=w, value=r["offset_ut"],
                threshold=t))
        if len(bad) > params.max_listed:
            findings.append(Finding("walk_offset", "fail", f"... and "
                                    f"{len(bad) - params.max_listed} more offset walks",
                                    "consistency", value=len(bad), threshold=t))
    t = th.get("disagreeing_cells_max_share")
    dis = out["disagreement_strength"]
    if t is not None and thr is not None and dis["share_above"] is not None \
            and dis["share_above"] > t:
        sd = arrays["disagreement_strength"]
        lab, regions = _regions(rgrid, np.nan_to_num(sd) > thr)
        cell, w, dev = arrays["_strength_cell_walk_dev"]
        lab_flat = lab.ravel()
        where = []
        for reg in regions[:5]:
            sel = (lab_flat[cell] == reg["label"]) & np.isfinite(dev)
            blame = pd.Series(dev[sel]).groupby(w[sel]).mean().sort_values(ascending=False)
            reg["walk"] = str(walk_ids[int(blame.index[0])]) if len(blame) else None
            where.append(reg)
        findings.append(Finding(
            "disagreement", "fail",
            f"{100 * dis['share_above']:.0f} % of the cells crossed by several walks disagree by "
            f"more than {thr:g} uT (allowed {100 * t:.0f} %); worst around "
            + "; ".join(f"{_fmt_xy(r)} (mostly walk {r['walk']})" for r in where[:3]),
            "consistency", walk=where[0]["walk"] if where else None,
            where={"regions": [{k: r[k] for k in ("x_m", "y_m", "bbox_m", "area_m2", "walk")}
                               for r in where]}, value=dis["share_above"], threshold=t))
    arrays.pop("_strength_cell_walk_dev", None)
    return out


# ----------------------------------------------------------------------------------------------
# 3. held-out accuracy

@contextlib.contextmanager
def _recording_holdout_metrics():
    """Record the per-walk (observed, predicted, x, y) arrays that
    :func:`mapping.holdout.leave_one_walk_out` hands to :func:`mapping.holdout.metrics`, in call
    order (for each layer, for each pipeline), so error maps use exactly the residuals the
    metrics were computed from. Not thread-safe (swaps a module attribute while it runs)."""
    calls: list = []
    original = holdout.metrics

    def recording(per_walk: list[tuple[NDArray, NDArray, NDArray, NDArray]]
                  ) -> dict[str, float]:
        calls.append(per_walk)
        return original(per_walk)

    holdout.metrics = recording
    try:
        yield calls
    finally:
        holdout.metrics = original


def _table_records(table: pd.DataFrame) -> list[dict]:
    return [{k: (v.item() if hasattr(v, "item") else v) for k, v in row.items()}
            for row in table.to_dict(orient="records")]


def heldout_section(bundle: MapBundle, fd: FloorData, th: dict, params: ValidateParams,
                    findings: list[Finding], arrays: dict, rgrid: Grid,
                    say: Callable[[str], None]) -> dict:
    raster, heading_raster, lev = _bundle_raster_params(bundle)
    mask = np.asarray(bundle.mask, dtype=bool)
    pipes = holdout.default_pipelines(raster)
    if not params.holdout_baseline:
        pipes = [p for p in pipes if p.constant or p.name == "indoormap default"]
    layers = tuple(params.holdout_layers)
    t0 = time.perf_counter()
    with _recording_holdout_metrics() as calls:
        table = holdout.leave_one_walk_out(
            fd.samples, bundle.grid, mask, pipes, layers=layers, levelling=lev,
            levelling_folds=params.holdout_levelling_folds, subsample=params.holdout_subsample,
            progress=lambda m: say(f"held-out: {m}"))
    out: dict = {
        "implementation": "mapping.holdout.leave_one_walk_out",
        "params": {"pipelines": [p.name for p in pipes], "layers": list(layers),
                   "subsample": params.holdout_subsample,
                   "levelling_folds": params.holdout_levelling_folds,
                   "raster": asdict(raster), "levelling": asdict(lev)},
        "seconds": round(time.perf_counter() - t0, 1),
        "table": _table_records(table)}
    say(f"held-out: {out['seconds']} s")
    # per-walk and per-cell views of the recorded residuals (checked against the table)
    sub = fd.samples.iloc[::params.holdout_subsample]
    walks = np.asarray(sorted(sub["trace_id"].unique()))
    residuals: dict[tuple[str, str], list] = {}
    consistent = len(calls) == len(layers) * len(pipes)
    if consistent:
        it = iter(calls)
        for layer in layers:
            for pipe in pipes:
                per_walk = next(it)
                row = table[(table["pipeline"] == pipe.name) & (table["layer"] == layer)]
                again = holdout.metrics(per_walk)
                if len(per_walk) != len(walks) or (again and not np.isclose(
                        again["rmse"], float(row["rmse"].iloc[0]), rtol=0, atol=1e-12)):
                    consistent = False
                residuals[(pipe.name, layer)] = per_walk
    if not consistent:
        findings.append(Finding("heldout_internal", "warn", "held-out residual maps are not "
                                "available (mapping.holdout changed how it reports); metrics "
                                "are unaffected", "heldout"))
        residuals = {}
    ours = "indoormap default"
    per_walk_out: dict[str, dict] = {}
    for layer in layers:
        pw = residuals.get((ours, layer))
        if pw is None:
            continue
        xs, ys, shape_res, abs_res = [], [], [], []
        for k, (o, p, x, y) in enumerate(pw):
            ok = np.isfinite(o) & np.isfinite(p)
            r = (p - o)[ok]
            rec = per_walk_out.setdefault(str(walks[k]), {})
            rec[f"{layer}_n"] = int(ok.sum())
            if ok.sum():
                med = float(np.median(r))
                rec[f"{layer}_median_ut"] = med
                rec[f"{layer}_shape_rmse_ut"] = float(np.sqrt(np.mean((r - med) ** 2)))
                xs.append(x[ok])
                ys.append(y[ok])
                shape_res.append(r - med)
                abs_res.append(r)
        if xs:
            xx, yy = np.concatenate(xs), np.concatenate(ys)
            arrays[f"heldout_rms_{layer}"] = _cell_reduce(rgrid, xx, yy,
                                                          np.concatenate(shape_res), rms=True,
                                                          min_count=3)[0]
        for pipe in pipes:
            pw2 = residuals.get((pipe.name, layer))
            if pw2 is not None:
                res = [(p - o)[np.isfinite(o) & np.isfinite(p)] for o, p, _, _ in pw2]
                arrays.setdefault("heldout_abs_residuals", {})[(pipe.name, layer)] = \
                    np.abs(np.concatenate(res)) if res else np.empty(0)
    out["per_walk"] = per_walk_out
    # summary percentiles of the default pipeline
    for layer in layers:
        a = arrays.get("heldout_abs_residuals", {}).get((ours, layer))
        if a is not None and len(a):
            out.setdefault("abs_error_percentiles", {})[layer] = {
                "median_ut": float(np.median(a)), "p90_ut": float(np.percentile(a, 90))}
    # heading offset
    if params.heading_holdout:
        try:
            out["heading_offset"] = heldout_heading_offset(fd.steps, bundle.grid, mask,
                                                           heading_raster, arrays, rgrid)
        except (ValueError, KeyError) as err:
            out["heading_offset"] = {"error": str(err)}
    # checks
    row = table[(table["pipeline"] == ours) & (table["layer"] == "strength")]
    if len(row):
        row = row.iloc[0]
        t = th.get("heldout_strength_shape_rmse_max_ut")
        if t is not None and np.isfinite(row["shape_rmse"]) and row["shape_rmse"] > t:
            findings.append(Finding("heldout_shape_rmse", "fail",
                                    f"held-out strength shape RMSE {row['shape_rmse']:.2f} uT "
                                    f"exceeds {t:g} uT", "heldout", value=row["shape_rmse"],
                                    threshold=t))
        t = th.get("heldout_skill_min")
        if t is not None and np.isfinite(row.get("skill", np.nan)) and row["skill"] < t:
            findings.append(Finding("heldout_skill", "fail",
                                    f"the map predicts held-out walks {'only ' if row['skill'] > 0 else ''}"
                                    f"with skill {row['skill']:.2f} against a constant map "
                                    f"(needs {t:g})", "heldout", value=row["skill"],
                                    threshold=t))
    ho = out.get("heading_offset", {})
    t = th.get("heading_offset_shape_rmse_max_deg")
    if t is not None and ho.get("shape_rmse") is not None and ho["shape_rmse"] > t:
        findings.append(Finding("heading_offset_shape_rmse", "fail",
                                f"held-out heading-offset shape RMSE {ho['shape_rmse']:.1f} deg "
                                f"exceeds {t:g} deg", "heldout", value=ho["shape_rmse"],
                                threshold=t))
    return out


def heldout_heading_offset(steps: pd.DataFrame, grid: Grid, mask: NDArray[np.bool_],
                           params: RasterParams, arrays: dict | None = None,
                           rgrid: Grid | None = None) -> dict:
    """Leave-one-walk-out of the heading-offset layer (deg), built as
    :func:`mapping.build.build_floor` builds it: the steps' local offsets plus the circular
    median of the other walks' median offsets, smoothed as unit vectors; predicted at the held-out
    walk's steps and compared with its own (absolute) offsets. Scored by
    :func:`mapping.holdout.metrics` on residuals wrapped to [-180, 180)."""
    st = steps[np.isfinite(steps["heading_offset_deg"]) & np.isfinite(steps["x_m"])
               & np.isfinite(steps["heading_offset_local_deg"])].reset_index(drop=True)
    if st["trace_id"].nunique() < 2:
        return {"error": "fewer than two walks with heading offsets"}
    walks = np.asarray(sorted(st["trace_id"].unique()))
    code = np.searchsorted(walks, st["trace_id"].to_numpy())
    x, y = st["x_m"].to_numpy(), st["y_m"].to_numpy()
    obs = st["heading_offset_deg"].to_numpy()
    local = np.radians(st["heading_offset_local_deg"].to_numpy())
    medians = np.array([circular_median_deg(obs[code == k]) for k in range(len(walks))])
    g_all = float(wrap_deg(circular_median_deg(medians)))
    stats = {}
    for name, comp in (("sin", np.sin(local)), ("cos", np.cos(local))):
        w, cell, mean = walk_cell_means(grid, x, y, comp, code)
        stats[name] = (w, cell, mean, cell_stats(grid, cell, mean))
    per_walk = []
    for k in range(len(walks)):
        sel = code == k
        preds = []
        for name in ("sin", "cos"):
            w, cell, mean, total = stats[name]
            mine = w == k
            st_k: CellStats = total - cell_stats(grid, cell[mine], mean[mine])
            preds.append(holdout._predict_windowed(grid, mask, st_k, params, x[sel], y[sel]))
        g_k = float(circular_median_deg(np.delete(medians, k)))
        pred = np.degrees(np.arctan2(preds[0], preds[1])) + g_k
        pc = g_all + wrap_deg(pred - g_all)  # continuous around the floor's offset
        o = pc + wrap_deg(obs[sel] - pc)
        per_walk.append((o, pc, x[sel], y[sel]))
    m = holdout.metrics(per_walk)
    res = [(p - o)[np.isfinite(p)] for o, p, _, _ in per_walk]
    allr = np.concatenate(res) if res else np.empty(0)
    m["coverage"] = float(np.isfinite(np.concatenate([p for _, p, _, _ in per_walk])).mean())
    m["p90_abs"] = float(np.percentile(np.abs(allr), 90)) if len(allr) else None
    m["unit"] = "deg"
    m["raster"] = asdict(params)
    if arrays is not None and rgrid is not None:
        xs, ys, sr = [], [], []
        for o, p, xx, yy in per_walk:
            ok = np.isfinite(p)
            if ok.sum():
                r = (p - o)[ok]
                xs.append(xx[ok])
                ys.append(yy[ok])
                sr.append(r - np.median(r))
        if xs:
            arrays["heldout_rms_heading_offset"] = _cell_reduce(
                rgrid, np.concatenate(xs), np.concatenate(ys), np.concatenate(sr), rms=True,
                min_count=2)[0]
        arrays.setdefault("heldout_abs_residuals", {})[("indoormap default",
                                                        "heading_offset")] = np.abs(allr)
    return m


# ----------------------------------------------------------------------------------------------
# 4. predicted localization quality

def predicted_section(bundle: MapBundle, noise: dict[str, float], th: dict,
                      params: ValidateParams, findings: list[Finding], arrays: dict) -> dict:
    g, mask = bundle.grid, np.asarray(bundle.mask, dtype=bool)
    info = np.zeros(g.shape)
    used = {}
    for layer in ("strength", "horizontal", "vertical"):
        if layer not in bundle.layers:
            continue
        v = np.asarray(bundle.layers[layer], dtype=np.float64)
        gy, gx = np.gradient(v, g.cell_m)
        grad2 = gx * gx + gy * gy
        sigma = noise.get(layer)
        if sigma is None or not np.isfinite(sigma) or sigma <= 0:
            continue
        used[layer] = float(sigma)
        info = info + grad2 / sigma ** 2
        if layer == "strength":
            arrays["gradient_strength"] = np.sqrt(grad2)
    out: dict = {"noise_ut": used,
                 "noise_source": noise.get("_source", "")}
    if not used:
        out["error"] = "no magnetic layers"
        return out
    with np.errstate(divide="ignore", invalid="ignore"):
        res = np.where(np.isfinite(info) & mask, 1.0 / np.sqrt(info), np.nan)
    arrays["magnetic_resolution_m"] = res
    fin = res[np.isfinite(res)]
    lim = th.get("magnetic_resolution_m") or 2.0
    out["magnetic_resolution_m"] = {
        "median": float(np.median(fin)) if fin.size else None,
        "p90": float(np.percentile(fin, 90)) if fin.size else None,
        "limit_m": lim,
        "flat_share": float((fin > lim).mean()) if fin.size else None,
        "mapped_cells": int(fin.size)}
    _, regions = _regions(g, np.nan_to_num(res, nan=0.0) > lim, min_area_m2=10.0)
    out["flat_regions"] = regions[:20]
    t = th.get("magnetic_flat_share_max")
    fs = out["magnetic_resolution_m"]["flat_share"]
    if t is not None and fs is not None and fs > t:
        findings.append(Finding(
            "magnetic_flat", "fail",
            f"{100 * fs:.0f} % of the mapped area is magnetically flat (the field changes by less "
            f"than one noise level over {lim:g} m; allowed {100 * t:.0f} %): the localizer will "
            "lean on dead reckoning and radio there", "predicted",
            where={"regions": [{k: r[k] for k in ("x_m", "y_m", "bbox_m", "area_m2")}
                               for r in regions[:5]]}, value=fs, threshold=t))
    elif regions:
        findings.append(Finding(
            "magnetic_flat", "warn",
            f"largest magnetically flat area: {regions[0]['area_m2']:.0f} m2 around "
            f"{_fmt_xy(regions[0])}", "predicted",
            where={k: regions[0][k] for k in ("x_m", "y_m", "bbox_m", "area_m2")}))
    return out


# ----------------------------------------------------------------------------------------------
# 5. calibration and 6. data quality

#: Leg flags that mean nothing on very short legs (see ``leg_min_length_m``).
NOISY_ON_SHORT_LEGS = frozenset({"speed", "step_length", "scale"})

def calibration_section(bundle: MapBundle, fd: FloorData | None, th: dict,
                        findings: list[Finding]) -> dict:
    out: dict = {"walks": []}
    if fd is not None:
        dev = dict(zip(fd.catalog["trace_id"], fd.catalog["device_model"]))
        for r in fd.pcat.itertuples(index=False):
            sm = r.summary if isinstance(r.summary, dict) else {}
            step = sm.get("step_model", {}) or {}
            out["walks"].append({
                "trace_id": r.trace_id, "device_model": dev.get(r.trace_id, ""),
                "session": r.session, "status": r.status,
                "calibration": sm.get("calibration"),
                "calibration_detail": sm.get("calibration_detail"),
                "step_model": step.get("model"), "step_k": step.get("k"),
                "heading_offset_median_deg": sm.get("heading_offset_median_deg")})
    elif bundle.has_table("source_walks"):
        sw = bundle.table("source_walks").to_pandas()
        out["walks"] = [{"trace_id": r.trace_id, "session": r.session,
                         "calibration": r.calibration} for r in sw.itertuples(index=False)]
    counts: dict[str, int] = {}
    for w in out["walks"]:
        if w.get("calibration"):
            counts[w["calibration"]] = counts.get(w["calibration"], 0) + 1
    out["decisions"] = counts
    bad = [w for w in out["walks"] if w.get("calibration") == "not-calibrated"]
    t = th.get("not_calibrated_walks_max")
    left_out = bool(field_left_out(bundle.manifest.get("metrics", {})))
    if t is not None and len(bad) > t:
        for w in bad:  # a fail only where the walk's field is in the magnetic layers
            findings.append(Finding("not_calibrated", "info" if left_out else "fail",
                                    f"walk {w['trace_id']}: magnetometer not calibrated "
                                    f"({w.get('calibration_detail') or 'no detail'})"
                                    + ("; left out of the magnetic layers by the build"
                                       if left_out else ""),
                                    "calibration", walk=w["trace_id"], value=len(bad),
                                    threshold=t))
    out["rssi_devices"] = _rssi_devices(bundle)
    return out


def _rssi_devices(bundle: MapBundle) -> dict:
    """Per-device RSSI (k, b) from a bundle table when the fingerprint stage wrote one."""
    for name in ("devices", "device_calibration", "rssi_devices"):
        if bundle.has_table(name):
            t = bundle.table(name).to_pandas()
            return {"source": f"bundle table {name}", "rows": _table_records(t)}
    return {"source": None, "rows": [], "note": "the bundle has no device RSSI table"}


def line_accounts(catalog: pd.DataFrame, bad_share_max: float | None
                  ) -> tuple[list[dict], list[Finding]]:
    """Per walk of a store catalog: its lines, bad lines, skipped lines and dropped rows (with
    the counts by reason), and a ``bad_lines`` finding for every walk whose share of bad lines
    exceeds ``bad_share_max`` (None: no check)."""
    lines, findings = [], []
    for r in catalog.itertuples(index=False):
        share = r.n_bad_lines / max(r.n_lines, 1)
        rec = {"trace_id": r.trace_id, "n_lines": int(r.n_lines),
               "n_bad_lines": int(r.n_bad_lines), "n_skipped_lines": int(r.n_skipped_lines),
               "n_dropped_rows": int(r.n_dropped_rows), "bad": json.loads(r.bad_json or "{}"),
               "skipped": json.loads(r.skipped_json or "{}"),
               "dropped": json.loads(r.dropped_json or "{}")}
        lines.append(rec)
        if bad_share_max is not None and share > bad_share_max:
            msgs = json.loads(r.messages_json or "[]")
            findings.append(Finding(
                "bad_lines", "fail", f"walk {r.trace_id} ({100 * share:.1f} % of its lines): "
                + bad_lines_summary(rec["bad"], msgs), "data_quality", walk=r.trace_id,
                value=share, threshold=bad_share_max))
    return lines, findings


def data_quality_section(bundle: MapBundle, fd: FloorData, th: dict, params: ValidateParams,
                         findings: list[Finding], arrays: dict) -> dict:
    out: dict = {}
    out["lines"], line_findings = line_accounts(fd.catalog, th.get("bad_line_share_max"))
    findings.extend(line_findings)
    out["lines_total"] = {k: int(sum(d[k] for d in out["lines"])) for k in
                          ("n_lines", "n_bad_lines", "n_skipped_lines", "n_dropped_rows")}
    # walks skipped by processing or not processed
    processed = set(fd.pcat["trace_id"])
    skipped = [{"trace_id": r.trace_id, "reason": r.reason or "skipped"}
               for r in fd.pcat.itertuples(index=False) if r.status != "ok"]
    skipped += [{"trace_id": t, "reason": "not processed (run indoormap process)"}
                for t in fd.catalog["trace_id"] if t not in processed]
    in_bundle = {w["trace_id"]: w["sha256"] for w in
                 bundle.manifest.get("build", {}).get("source_walks", [])}
    ok_walks = dict(zip(fd.pcat.loc[fd.pcat["status"] == "ok", "trace_id"],
                        fd.pcat.loc[fd.pcat["status"] == "ok", "sha256"]))
    out["walks_skipped"] = skipped
    out["walks_ok"] = len(ok_walks)
    out["walks_in_bundle"] = len(in_bundle)
    out["walks_not_in_bundle"] = list(fd.not_in_bundle)
    if fd.not_in_bundle:
        findings.append(Finding(
            "walks_not_in_bundle", "info", f"{len(fd.not_in_bundle)} walk(s) of the floor in "
            f"the store are not among the bundle's source walks (build --exclude, or "
            f"ingested later) and are left out of this report: "
            + ", ".join(fd.not_in_bundle[:params.max_listed])
            + (" ..." if len(fd.not_in_bundle) > params.max_listed else ""), "data_quality"))
    mismatch = sorted(set(in_bundle.items()) ^ set(ok_walks.items()))
    out["store_matches_bundle"] = not mismatch
    if mismatch:
        findings.append(Finding(
            "store_mismatch", "warn", f"the store's processed walks differ from the bundle's "
            f"source walks ({len(set(in_bundle) - set(ok_walks))} only in the bundle, "
            f"{len(set(ok_walks) - set(in_bundle))} only in the store, others changed): the "
            "report describes the store's data", "data_quality"))
    t = th.get("skipped_walks_max")
    if t is not None and len(skipped) > t:
        for s in skipped[:params.max_listed]:
            findings.append(Finding("walk_skipped", "fail",
                                    f"walk {s['trace_id']} was not used: {s['reason']}",
                                    "data_quality", walk=s["trace_id"], value=len(skipped),
                                    threshold=t))
    # flagged legs
    legs = fd.legs.copy()
    flags = legs["flags"].fillna("").astype(str)
    exploded = flags.str.split(",").explode()
    exploded = exploded[exploded != ""]
    out["legs_total"] = len(legs)
    out["legs_flagged"] = int((flags != "").sum())
    out["flag_counts"] = {str(k): int(v) for k, v in exploded.value_counts().items()}
    fail_flags = set(th.get("leg_flags_fail") or [])
    min_len = float(th.get("leg_min_length_m") or 0.0)
    flagged = []
    s = fd.samples
    seg_xy = []
    for tid, grp in legs[flags != ""].groupby("trace_id", sort=True):
        items = []
        for r in grp.itertuples(index=False):
            fl = [f for f in str(r.flags).split(",") if f]
            judged = [f for f in fl if not (f in NOISY_ON_SHORT_LEGS
                                            and float(r.distance_m) < min_len)]
            items.append({"leg": int(r.leg), "flags": fl, "judged_flags": judged,
                          "distance_m": float(r.distance_m),
                          "waypoint_residual_m": float(r.waypoint_residual_m),
                          "speed_mps": float(r.speed_mps), "scale": float(r.scale)})
            sel = (s["trace_id"] == tid) & (s["leg"] == r.leg)
            seg_xy.append((tid, int(r.leg), fl, s.loc[sel, "x_m"].to_numpy()[::5],
                           s.loc[sel, "y_m"].to_numpy()[::5]))
        flagged.append({"trace_id": tid, "legs": items})
        fails = [i for i in items if set(i["judged_flags"]) & fail_flags]
        warns = [i for i in items if i not in fails]
        for sev, group in (("fail", fails), ("warn", warns)):
            if not group:
                continue
            desc = "; ".join(f"leg {i['leg']} ({i['distance_m']:.1f} m): {', '.join(i['flags'])}"
                             + (f" (track misses its waypoint by {i['waypoint_residual_m']:.1f} m)"
                                if "waypoint" in i["flags"] else "") for i in group)
            xy = [(x, y) for t_, lg, _, x, y in seg_xy if t_ == tid
                  and lg in {i["leg"] for i in group} and len(x)]
            where = None
            if xy:
                ax = np.concatenate([a for a, _ in xy])
                ay = np.concatenate([b for _, b in xy])
                where = {"x_m": float(np.median(ax)), "y_m": float(np.median(ay)),
                         "bbox_m": [float(ax.min()), float(ay.min()), float(ax.max()),
                                    float(ay.max())], "legs": [i["leg"] for i in group]}
            findings.append(Finding(
                "leg_flags", sev, f"walk {tid}: {desc}"
                + ("; check the waypoint clicks or walk these legs again" if sev == "fail"
                   else ""), "data_quality", walk=tid, where=where,
                value=len(group), threshold=sorted(fail_flags)))
    out["flagged_legs"] = flagged
    out["walks_with_failing_legs"] = sum(
        1 for w in flagged if any(set(i["judged_flags"]) & fail_flags for i in w["legs"]))
    arrays["flagged_segments"] = seg_xy
    # waypoints outside the reachable area
    wp = fd.waypoints
    tol = th.get("waypoint_outside_tolerance_m") or 0.0
    wx, wy = wp["x_m"].to_numpy(np.float64), wp["y_m"].to_numpy(np.float64)
    d = distance_to_reachable_m(bundle.grid, np.asarray(bundle.mask, dtype=bool), wx, wy)
    outside = d > tol
    order = wp.groupby("trace_id").cumcount().to_numpy()
    out_rows = [{"trace_id": str(t), "waypoint": int(i), "t_ms": int(tm), "x_m": float(x),
                 "y_m": float(y), "distance_m": float(dd) if np.isfinite(dd) else None}
                for t, i, tm, x, y, dd in zip(wp["trace_id"].to_numpy()[outside],
                                              order[outside], wp["t_ms"].to_numpy()[outside],
                                              wx[outside], wy[outside], d[outside])]
    out["waypoints_total"] = len(wp)
    out["waypoints_outside"] = out_rows
    arrays["waypoints"] = (wx, wy, outside)
    t = th.get("waypoints_outside_max")
    if t is not None and len(out_rows) > t:
        for w in out_rows[:params.max_listed]:
            findings.append(Finding(
                "waypoint_outside", "fail",
                f"walk {w['trace_id']}: waypoint {w['waypoint']} at ({w['x_m']:.1f}, "
                f"{w['y_m']:.1f}) m is "
                + (f"{w['distance_m']:.1f} m outside the reachable area"
                   if w["distance_m"] is not None else "off the floor plan"),
                "data_quality", walk=w["trace_id"], where={"x_m": w["x_m"], "y_m": w["y_m"]},
                value=w["distance_m"], threshold=tol))
    return out


# ----------------------------------------------------------------------------------------------
# 7. radio

def radio_section(bundle: MapBundle, store: SurveyStore | str | Path | None,
                  fd: FloorData | None, th: dict, findings: list[Finding], arrays: dict,
                  rgrid: Grid | None = None,
                  progress: Callable[[str], None] | None = None) -> dict:
    """Wi-Fi/BLE held-out positioning, the site's floor accuracy and the radio bound
    (:func:`mapping.radio_validation.radio_summary`); ``{"available": False, "reason": ...}``
    when the bundle has no fingerprints."""
    from .radio_validation import radio_summary

    if not any(bundle.has_table(f"{k}_fp") for k in ("wifi", "ble")):
        return {"available": False, "reason": "radio: the bundle has no Wi-Fi or BLE "
                                              "fingerprints (a survey without radio rows)"}
    floor = fd.floor if fd is not None else (bundle.manifest.get("floor_name") or "")
    res = radio_summary(bundle, store, floor, fd.site if fd is not None else None,
                        leave_out=fd.not_in_bundle if fd is not None else (),
                        progress=progress)
    out = {"available": True, **{k: v for k, v in res.items() if k != "arrays"}}
    ra = res.get("arrays", {})
    arrays.update({k: v for k, v in ra.items() if not k.endswith("_error_points")})
    kind = res.get("primary_kind")
    if f"{kind}_error_points" in ra:  # median held-out error per report cell
        xy, err = ra[f"{kind}_error_points"]
        rgrid = report_grid_of(bundle.grid, ValidateParams().report_cell_m if rgrid is None
                               else rgrid.cell_m)
        r, c, inside = rgrid.cell_of(xy[:, 0], xy[:, 1])
        cells = pd.DataFrame({"cell": (r * rgrid.width + c)[inside], "e": err[inside]})
        med = cells.groupby("cell")["e"].median()
        emap = np.full(rgrid.width * rgrid.height, np.nan)
        emap[med.index.to_numpy()] = med.to_numpy()
        arrays["radio_error_map_m"] = emap.reshape(rgrid.shape)
    t = th.get("radio_median_error_max_m")
    v = out.get("median_error_m")
    if t is not None and v is not None and v > t:
        findings.append(Finding("radio_error", "fail", f"held-out radio median error {v:.1f} m "
                                f"exceeds {t:g} m", "radio", value=v, threshold=t))
    t = th.get("radio_floor_accuracy_min")
    v = out.get("floor_accuracy")
    if t is not None and v is not None and v < t:
        findings.append(Finding("radio_floor", "fail", f"held-out floor accuracy {v:.2f} below "
                                f"{t:g}", "radio", value=v, threshold=t))
    return out


# ----------------------------------------------------------------------------------------------
# the whole validation

def validate_bundle(bundle: MapBundle | str | Path,
                    store: SurveyStore | str | Path | None = None, *,
                    thresholds: dict | None = None, params: ValidateParams = ValidateParams(),
                    floor_dir: str | Path | None = None,
                    progress: Callable[[str], None] | None = None) -> ValidationResult:
    """Validate a floor bundle (with its survey store for everything beyond the rasters).

    Parameters
    ----------
    bundle : MapBundle or path
    store : SurveyStore or path, optional
        The processed store the bundle was built from. Without it only the bundle's own
        content is checked (coverage from its manifest, levelling, predicted quality with a
        nominal noise level).
    thresholds : dict, optional
        Thresholds to change from :data:`DEFAULT_THRESHOLDS` (``None`` disables a check), as
        :func:`load_thresholds` takes them: the others keep their defaults, and an unknown
        key is a :class:`ValidationError` (a typo must not disable a check).
    floor_dir : path, optional
        Floor folder with ``floor_image.png`` / ``geojson_map.json`` for the figures (default:
        found from the store's source paths).
    """
    say = progress or (lambda msg: None)
    t_start = time.perf_counter()
    b = bundle if isinstance(bundle, MapBundle) else load_bundle(bundle)
    if b.grid is None or b.mask is None:
        raise ValidationError(f"{b.path}: not a floor bundle (no grid)")
    th = load_thresholds(overrides=thresholds)  # partial: the rest are the defaults
    findings: list[Finding] = []
    arrays: dict = {}
    timings: dict[str, float] = {}
    rgrid = report_grid_of(b.grid, params.report_cell_m)
    arrays["report_mask"] = _report_mask(b.grid, np.asarray(b.mask, bool), rgrid)
    m = b.manifest
    metrics: dict = {
        "bundle": {"path": str(b.path), "bundle_id": b.bundle_id, "site_id": b.site_id,
                   "floor_name": m.get("floor_name"), "grid": b.grid.to_dict(),
                   "layers": sorted(b.layers), "tables": sorted(m.get("tables", {})),
                   "build_time": m.get("build", {}).get("build_time"),
                   "n_walks": len(m.get("build", {}).get("source_walks", [])),
                   "manifest_metrics": m.get("metrics", {})},
        "params": params.to_dict()}

    def timed(name: str, fn: Callable[[], _T]) -> _T:
        t = time.perf_counter()
        res = fn()
        timings[name] = round(time.perf_counter() - t, 2)
        return res

    fd = None
    if store is not None:
        from survey.store import SurveyStore

        store = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
        say("load the store's data of the floor")
        fd = timed("load", lambda: load_floor_data(store, b))
        metrics["store"] = {"path": str(store.root), "floor": fd.floor,
                            "site": fd.site, "walks": int(fd.samples["trace_id"].nunique()),
                            "samples": len(fd.samples)}
    else:
        findings.append(Finding("no_store", "warn", "no survey store given (--store): only the "
                                "bundle itself was checked; held-out accuracy, consistency and "
                                "data quality need the store", "summary"))
    fdir = Path(floor_dir) if floor_dir else floor_dir_of(fd)
    if floor_dir:  # a folder given by hand: said when it cannot be this floor's
        problem = floor_dir_problem(fdir, b.manifest)
        if problem:
            findings.append(Finding("floor_dir", "warn", problem, "summary"))
    say("coverage")
    metrics["coverage"] = timed("coverage", lambda: coverage_section(b, fd, th, params, findings,
                                                                    arrays))
    noise: dict = {}
    if fd is not None:
        say("consistency")
        metrics["consistency"] = timed("consistency", lambda: consistency_section(
            b, fd, th, params, findings, arrays, rgrid))
        n_walks = int(fd.samples["trace_id"].nunique())
        if params.holdout and n_walks < 3:
            findings.append(Finding("heldout_skipped", "warn", f"held-out accuracy needs at "
                                    f"least 3 walks on the floor, it has {n_walks}", "heldout"))
        elif params.holdout:
            say("held-out accuracy (leave one walk out)")
            metrics["heldout"] = timed("heldout", lambda: heldout_section(
                b, fd, th, params, findings, arrays, rgrid, say))
            tab = pd.DataFrame(metrics["heldout"]["table"])
            ours = tab[tab["pipeline"] == "indoormap default"] if len(tab) else tab
            noise = {r["layer"]: r.get("shape_rmse") for r in ours.to_dict(orient="records")
                     if r.get("shape_rmse") is not None and np.isfinite(r["shape_rmse"])}
            if "horizontal" not in noise and noise:
                noise["horizontal"] = float(np.mean(list(noise.values())))
            noise["_source"] = "held-out shape RMSE per layer (horizontal: mean of the others " \
                               "when not held out)"
        say("data quality")
        metrics["data_quality"] = timed("data_quality", lambda: data_quality_section(
            b, fd, th, params, findings, arrays))
    if not noise:
        # no held-out figures: the map's own uncertainty plus a nominal 1 uT sensor noise
        for layer in ("strength", "horizontal", "vertical"):
            if layer in b.std:
                sd = np.asarray(b.std[layer], dtype=np.float64)
                sd = sd[np.isfinite(sd)]
                noise[layer] = float(np.sqrt(1.0 + (np.median(sd) ** 2 if sd.size else 0.0)))
        noise["_source"] = "nominal: sqrt(1 uT^2 + median map std^2) (no held-out figures)"
    say("predicted localization quality")
    metrics["predicted"] = timed("predicted", lambda: predicted_section(b, noise, th, params,
                                                                       findings, arrays))
    metrics["calibration"] = timed("calibration", lambda: calibration_section(b, fd, th,
                                                                             findings))
    if params.radio:
        say("radio")
        metrics["radio"] = timed("radio", lambda: radio_section(
            b, store, fd, th, findings, arrays, rgrid, progress=say))
        if not metrics["radio"].get("available"):
            findings.append(Finding("radio", "info", metrics["radio"]["reason"], "radio"))
    metrics["timings_s"] = {**timings, "total": round(time.perf_counter() - t_start, 2)}
    _derived_metrics(metrics)
    metrics["checks"] = _check_table(th, metrics, findings)
    return ValidationResult(metrics=metrics, findings=findings, thresholds=th, arrays=arrays,
                            bundle=b, report_grid=rgrid, floor_dir=fdir)


#: The checks of the summary table: (title, threshold key, finding check name, how the value
#: is read from the metrics, comparison). The verdict comes from the findings; the table shows
#: the value each check saw.
CHECKS: tuple[tuple[str, str, str, str, str], ...] = (
    ("coverage within 2 m", "coverage_within_2m_min", "coverage_within_2m_min",
     "coverage.euclidean.within_2m", ">="),
    ("coverage within 5 m", "coverage_within_5m_min", "coverage_within_5m_min",
     "coverage.euclidean.within_5m", ">="),
    ("largest unsupported region (m2)", "unsupported_region_max_m2", "unsupported_region",
     "coverage.largest_unsupported_m2", "<="),
    ("largest walk offset (uT)", "walk_offset_max_ut", "walk_offset",
     "consistency.max_walk_offset_ut", "<="),
    ("cells where walks disagree (share)", "disagreeing_cells_max_share", "disagreement",
     "consistency.disagreement_strength.share_above", "<="),
    ("largest levelling residual (uT)", "levelling_residual_max_ut", "levelling_residual",
     "consistency.max_levelling_residual_ut", "<="),
    ("held-out strength shape RMSE (uT)", "heldout_strength_shape_rmse_max_ut",
     "heldout_shape_rmse", "heldout.strength_shape_rmse_ut", "<="),
    ("held-out strength skill", "heldout_skill_min", "heldout_skill",
     "heldout.strength_skill", ">="),
    ("held-out heading-offset shape RMSE (deg)", "heading_offset_shape_rmse_max_deg",
     "heading_offset_shape_rmse", "heldout.heading_offset.shape_rmse", "<="),
    ("magnetically flat share", "magnetic_flat_share_max", "magnetic_flat",
     "predicted.magnetic_resolution_m.flat_share", "<="),
    ("walks not calibrated", "not_calibrated_walks_max", "not_calibrated",
     "calibration.n_not_calibrated", "<="),
    ("largest bad-line share", "bad_line_share_max", "bad_lines",
     "data_quality.max_bad_line_share", "<="),
    ("walks with failing leg flags", "leg_flags_fail", "leg_flags",
     "data_quality.walks_with_failing_legs", "== 0"),
    ("waypoints outside the reachable area", "waypoints_outside_max", "waypoint_outside",
     "data_quality.n_waypoints_outside", "<="),
    ("walks skipped", "skipped_walks_max", "walk_skipped", "data_quality.n_walks_skipped",
     "<="),
    ("fewest walks in a zone", "zone_min_walks", "zone_walks", "coverage.min_zone_walks", ">="),
    ("radio median error (m)", "radio_median_error_max_m", "radio_error",
     "radio.median_error_m", "<="),
    ("radio floor accuracy", "radio_floor_accuracy_min", "radio_floor", "radio.floor_accuracy",
     ">="),
)


def _lookup(metrics: dict, path: str):
    cur = metrics
    for part in path.split("."):
        if isinstance(cur, list):
            if not part.isdigit() or int(part) >= len(cur):
                return None
            cur = cur[int(part)]
        elif isinstance(cur, dict):
            cur = cur.get(part)
        else:
            return None
        if cur is None:
            return None
    return cur


def _check_table(th: dict, metrics: dict, findings: list[Finding]) -> list[dict]:
    """One row per check: title, threshold, value seen and status (``pass``, ``fail``, ``off``
    when its threshold is None, ``not run`` when its input was missing)."""
    failed = {f.check for f in findings if f.severity == "fail"}
    rows = []
    for title, key, check, path, op in CHECKS:
        t = th.get(key)
        v = _lookup(metrics, path)
        if isinstance(t, list):
            t_text = ", ".join(t)
        else:
            t_text = t
        if check in failed:
            status = "fail"
        elif t is None or (isinstance(t, list) and not t):
            status = "off"
        elif v is None:
            status = "not run"
        else:
            status = "pass"
        rows.append({"check": check, "title": title, "threshold_key": key, "threshold": t_text,
                     "op": op, "value": v, "status": status})
    return rows


def _derived_metrics(metrics: dict) -> None:
    """Single numbers the check table reads (maxima and counts over the lists)."""
    con = metrics.get("consistency")
    if con:
        offs = [r["offset_ut"] for r in con.get("walk_offsets_ut", {}).values()
                if r.get("offset_ut") is not None]
        con["max_walk_offset_ut"] = max(offs) if offs else None
        lev = [r["norm_ut"] for r in con.get("levelling", [])]
        con["max_levelling_residual_ut"] = max(lev) if lev else None
    ho = metrics.get("heldout")
    if ho:
        for r in ho.get("table", []):
            if r["pipeline"] == "indoormap default" and r["layer"] == "strength":
                ho["strength_shape_rmse_ut"] = r.get("shape_rmse")
                ho["strength_skill"] = r.get("skill")
    cov = metrics.get("coverage")
    if cov and "zones" in cov:
        z = [d["walks"] for d in cov["zones"]]
        cov["min_zone_walks"] = min(z) if z else None
    if cov and cov.get("unsupported_regions") is not None:
        regs = cov["unsupported_regions"]
        cov["largest_unsupported_m2"] = regs[0]["area_m2"] if regs else 0.0
    cal = metrics.get("calibration")
    if cal:
        cal["n_not_calibrated"] = sum(1 for w in cal.get("walks", [])
                                      if w.get("calibration") == "not-calibrated")
    dq = metrics.get("data_quality")
    if dq:
        shares = [d["n_bad_lines"] / max(d["n_lines"], 1) for d in dq.get("lines", [])]
        dq["max_bad_line_share"] = max(shares) if shares else None
        dq["n_waypoints_outside"] = len(dq.get("waypoints_outside", []))
        dq["n_walks_skipped"] = len(dq.get("walks_skipped", []))


def write_metrics(result: ValidationResult, out_dir: str | Path) -> Path:
    """Write ``metrics.json`` (atomically) into ``out_dir``; returns its path."""
    from survey.publish import atomic_write_bytes

    path = Path(out_dir) / "metrics.json"
    atomic_write_bytes(path, json.dumps(result.to_json(), indent=1, sort_keys=True,
                                        allow_nan=False).encode(), overwrite=True)
    return path


def summary_lines(result: ValidationResult) -> list[str]:
    """A short text summary (what the CLI prints)."""
    m = result.metrics
    b = m["bundle"]
    lines = [f"{b['site_id']}/{b['floor_name']} bundle {b['bundle_id'][:16]}: "
             f"{result.verdict_text()}"]
    cov = m.get("coverage", {}).get("euclidean", {})
    if cov:
        lines.append("coverage: " + ", ".join(f"{100 * v:.0f} % within {k[7:]}"
                                              for k, v in cov.items()))
    ho = m.get("heldout")
    if ho:
        for r in ho["table"]:
            if r["pipeline"] == "indoormap default":
                lines.append(f"held-out {r['layer']}: RMSE {r['rmse']:.2f} uT, shape RMSE "
                             f"{r['shape_rmse']:.2f} uT, skill {r.get('skill', float('nan')):.2f}")
        hd = ho.get("heading_offset", {})
        if hd.get("rmse") is not None:
            lines.append(f"held-out heading offset: RMSE {hd['rmse']:.1f} deg, shape RMSE "
                         f"{hd['shape_rmse']:.1f} deg")
    left_out = m.get("data_quality", {}).get("walks_not_in_bundle", [])
    if left_out:
        lines.append(f"{len(left_out)} walk(s) of the store not in the bundle left out")
    warns = [f for f in result.findings if f.severity == "warn"]
    said = ("no_store", "floor_dir")  # said here, not only in the report
    lines += [f"warning: {f.message}" for f in warns if f.check in said]
    others = sum(f.check not in said for f in warns)
    if others:
        lines.append(f"{others} warning(s) in the report")
    fails = result.failed
    if fails:
        lines.append(f"{len(fails)} problem(s):")
        lines += [f"  - [{f.check}] {f.message}" for f in fails[:20]]
        if len(fails) > 20:
            lines.append(f"  ... {len(fails) - 20} more in the report")
    return lines
