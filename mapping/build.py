"""Building the map bundle of a floor from a processed survey store.

Steps: processed samples of the floor -> per-session levelling (:mod:`mapping.levelling`) ->
layers on the reachable-area mask (:mod:`mapping.interpolate`): ``strength``, ``horizontal``,
``vertical`` (uT), ``azimuth``, ``polar`` (deg) of the levelled map-frame field and
``heading_offset`` (deg, compass heading minus walking direction) from the steps -> tables
(source walks, levelling) -> :class:`~mapping.bundle_writer.BundleContent`.

Deterministic: the same store, floor plan and parameters give the same bundle bytes. The build
time written to the manifest is ``BuildParams.build_time`` (default: the end of the newest
source walk, so rebuilding the same data gives the same bytes).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Collection, Iterable
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timezone

import numpy as np
import pandas as pd
import pyarrow as pa
from numpy.typing import NDArray

from localize.bundle import Grid
from survey.errors import IndoormapError
from survey.field_features import circular_median_deg, wrap_deg
from survey.memory import release_free_memory
from survey.process_store import processed_floors_text, processed_table, processed_walks, \
    walks_per_site
from survey.store import SurveyStore

from .bundle_writer import BundleContent, Layer
from .floorplan import FloorPlan
from .grid import reachable_distance_raster_m, reachable_mask
from .field_layers import FIELD_LAYERS, field_rasters, floor_steps, levelling_samples, \
    reduce_field
from .holdout import BANDWIDTH_CANDIDATES_M, choose_smoothing, heldout_quality
from .interpolate import DEGREE, RasterParams, raster
from .levelling import LevellingParams, empty_residuals, fit_session_residuals
from .radio_build import RadioParams, SiteRadio, build_site_radio


class BuildError(IndoormapError, ValueError):
    """A bundle cannot be built from these inputs."""


@dataclass(frozen=True)
class BuildParams:
    """Map-building parameters (lengths in m)."""

    cell_m: float = 0.5
    #: when the chosen kernel bandwidth is at most ``2 * cell_m``, raster (and choose again) on
    #: cells of this size (m), so that the cells resolve the kernel (``cell_m`` keeps it)
    min_cell_m: float = 0.25
    raster: RasterParams = field(default_factory=RasterParams)
    heading_raster: RasterParams = field(
        default_factory=lambda: RasterParams(method="kernel", bandwidth_m=2.0))
    levelling: LevellingParams = field(default_factory=LevellingParams)
    level: bool = True
    #: Wi-Fi/BLE fingerprints and device table in the floor bundle (see mapping.radio_build)
    radio: RadioParams | None = field(default_factory=RadioParams)
    #: choose the kernel bandwidth by grouped cross-validation (``raster.bandwidth_m`` if off)
    auto_bandwidth: bool = True
    build_time: str | None = None
    seed: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


def _time_text(ms: float) -> str:
    return datetime.fromtimestamp(ms / 1000.0, tz=timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def coverage(grid: Grid, mask: NDArray[np.bool_], support: NDArray[np.bool_],
             distances_m: Iterable[float] = (1.0, 2.0, 5.0)) -> dict[str, float]:
    """Share of reachable cells within each distance of a survey sample (``support``: cells
    holding a sample, bool of the grid's shape)."""
    from scipy import ndimage

    dist = ndimage.distance_transform_edt(~support) * grid.cell_m
    n = max(int(mask.sum()), 1)
    return {f"within_{d:g}m": float((mask & (dist <= d)).sum() / n) for d in distances_m}


#: Share of a floor's samples within :data:`ON_PLAN_M` of the plan's reachable area below
#: which a build refuses the floor: most of the survey lies off the plan, so the plan is of
#: another floor, in another frame or units, or covers part of the walks (its maps would be
#: judged on the sliver inside and its fingerprints placed off the map).
MIN_SAMPLES_ON_PLAN = 0.5
#: How far (m) outside the reachable area a sample still counts as on the plan (the walks'
#: positions stray 1-2 m from the lines walked).
ON_PLAN_M = 2.0


def near_plan_of(grid: Grid, mask: NDArray[np.bool_]
                 ) -> Callable[[NDArray, NDArray], NDArray[np.bool_]]:
    """A function of positions ``(x_m, y_m)`` (m, shape (n,) each) telling which lie within
    :data:`ON_PLAN_M` of a reachable cell of ``mask`` (the grid's shape; off the grid: not);
    the distance transform is made once, for every call."""
    near_cells = reachable_distance_raster_m(grid, mask) <= ON_PLAN_M

    def near_plan(x_m: NDArray, y_m: NDArray) -> NDArray[np.bool_]:
        row, col, inside = grid.cell_of(x_m, y_m)
        return inside & near_cells[row, col]

    return near_plan


def samples_on_plan(near_plan: Callable[[NDArray, NDArray], NDArray[np.bool_]], x_m: NDArray,
                    y_m: NDArray) -> float:
    """Share of the positions ``(x_m, y_m)`` (m, shape (n,)) for which ``near_plan`` is true
    (within :data:`ON_PLAN_M` of a reachable cell, say); 1.0 for no positions."""
    if len(x_m) == 0:
        return 1.0
    return float(near_plan(x_m, y_m).mean())


def build_smoothing(samples: pd.DataFrame, field_enu: np.ndarray, grid: Grid,
                    mask: NDArray[np.bool_],
                    params: BuildParams) -> tuple[RasterParams, dict[str, float]]:
    """The kernel bandwidth and shrinkage a build chooses, from the floor's samples in memory:
    grouped cross-validation of the levelled strength over walks
    (:func:`mapping.holdout.choose_smoothing` on every 5th sample, the ones :func:`build_floor`
    takes walk by walk)."""
    return choose_smoothing(grid, mask, samples["x_m"].to_numpy(), samples["y_m"].to_numpy(),
                            np.linalg.norm(field_enu, axis=1), samples["trace_id"].to_numpy(),
                            params.raster)


def raster_cell_m(params: BuildParams, bandwidth_m: float) -> float:
    """Cell size (m) of a floor rastered with ``bandwidth_m``: ``params.cell_m``, or
    ``params.min_cell_m`` when the kernel is two cells wide or narrower (the finest cells,
    where the choice is made again: a local polynomial often picks a wider kernel on coarse
    cells than the fine cells then support)."""
    return float(params.cell_m if bandwidth_m > 2 * params.cell_m
                 else min(params.cell_m, params.min_cell_m))


def heading_raster_for(heading: RasterParams, bandwidth_m: float) -> RasterParams:
    """The heading-offset raster of a floor whose field layers were given the bandwidth
    ``bandwidth_m`` (m) by cross-validation: the same bandwidth, at least 1 m (the offsets are
    per step, about 0.7 m apart)."""
    return replace(heading, bandwidth_m=max(float(bandwidth_m), 1.0))


def floor_samples(store: SurveyStore, site: str | None, floor: str) -> pd.DataFrame:
    """Processed samples of a floor with their session, all in memory (validation and
    benchmarks; the build reads walk by walk)."""
    pcat = floor_walks(store, site, floor)
    samples = processed_table(store, "samples", site=site, floor=floor)
    samples["session"] = samples["trace_id"].map(dict(zip(pcat["trace_id"], pcat["session"])))
    return samples


def field_left_out(metrics: dict) -> list[str]:
    """Trace ids of the walks a floor's build kept out of its magnetic layers for a
    magnetometer not calibrated (its ``metrics.not_calibrated_walks``); empty when there are
    none, or when no walk was calibrated and they made the layers."""
    raw = metrics.get("not_calibrated_walks") or {}
    return [] if raw.get("in_magnetic_layers", True) else list(raw.get("trace_ids", []))


def floor_walks(store: SurveyStore, site: str | None, floor: str,
                exclude_walks: Collection[str] = ()) -> pd.DataFrame:
    """Processed-catalog rows of the floor's walks that processed ``ok``, minus
    ``exclude_walks`` (trace ids of the store); raises :class:`BuildError` when none is left
    or an excluded id is not in the store."""
    if isinstance(exclude_walks, str):
        raise TypeError("exclude_walks is a collection of trace ids, not one string")
    unknown = sorted(set(map(str, exclude_walks)) - set(store.catalog()["trace_id"].astype(str))
                     ) if len(exclude_walks) else []
    if unknown:  # a typo or a file name would leave the walk in the map, unseen
        shown = ", ".join(unknown[:3]) + (", ..." if len(unknown) > 3 else "")
        raise BuildError(f"{store.root}: exclude_walks names {len(unknown)} trace id(s) the "
                         f"store does not hold: {shown} (trace ids, not file names)")
    pcat = processed_walks(store, site=site, floor=floor)
    where = f"floor {floor!r}" + (f" of site {site!r}" if site else "")
    if not len(pcat):
        raise BuildError(f"{store.root}: no processed walks for {where}; "
                         f"{processed_floors_text(store)}")
    pcat = pcat[~pcat["trace_id"].isin(list(exclude_walks))]
    if not len(pcat):
        raise BuildError(f"{store.root}: every processed walk of {where} is excluded")
    if site is None and pcat["site"].nunique() > 1:  # one map would merge two buildings
        raise BuildError(f"{store.root}: {where} has walks of several sites ("
                         f"{walks_per_site(pcat)}); give the site to build")
    return pcat.reset_index(drop=True)


def build_floor(store: SurveyStore | str, plan: FloorPlan, *, floor: str,
                site: str | None = None, params: BuildParams = BuildParams(),
                radio: SiteRadio | None = None, exclude_walks: Collection[str] = (),
                progress: Callable[[str], None] | None = None) -> BundleContent:
    """Build the bundle content of one floor (write it with :func:`write_bundle`).

    ``radio``: the site's radio maps (:func:`mapping.radio_build.build_site_radio` over all its
    floors, so that the device table and AP selection see every floor); default: computed from
    this floor alone when ``params.radio`` is set. ``exclude_walks``: trace ids left out of the
    map (held-out evaluation; a ``radio`` passed in must leave them out too).

    The samples are read walk by walk (:mod:`mapping.field_layers`): memory grows with the
    grid, the walks' cells, the steps and two subsamples (every 5th sample), never with the
    whole samples table.
    """
    store = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
    say = progress or (lambda msg: None)
    pcat = floor_walks(store, site, floor, exclude_walks)
    cat = store.traces(site, floor).set_index("trace_id")
    grid = plan.grid(params.cell_m)
    mask = reachable_mask(grid, plan.reachable)
    if not mask.any():
        raise BuildError(f"floor {floor}: the reachable area is empty at {params.cell_m} m cells")
    say(f"{floor}: {len(pcat)} walks")
    calibration = np.array([json.loads(sj).get("calibration", "") for sj in pcat["summary_json"]])
    raw = calibration == "not-calibrated"
    # a raw magnetometer reads the phone's hard iron (tens of uT, turning with the phone) as
    # field: such walks stay out of the magnetic layers while calibrated walks make them
    field_walks = pcat[~raw] if (~raw).any() else pcat
    if raw.any():
        say(f"{floor}: {int(raw.sum())} walk(s) with a magnetometer not calibrated: "
            + ("left out of the magnetic layers" if (~raw).any() else
               "they make the magnetic layers, no walk of the floor being calibrated"))
    residuals = None
    if params.level:
        residuals = fit_session_residuals(
            levelling_samples(store, field_walks, params.levelling.subsample),
            replace(params.levelling, subsample=1))
        say(f"{floor}: levelled {int((residuals['n_pairs'] > 0).sum())} of "
            f"{len(residuals)} sessions")
    reduction = reduce_field(store, field_walks, grid, residuals,
                         progress=lambda i, n: say(f"{floor}: read walk {i}/{n}")
                         if i == n or i % 100 == 0 else None)
    release_free_memory()  # the walks' freed buffers
    say(f"{floor}: {reduction.n_samples} samples")
    near_plan = near_plan_of(grid, mask)  # made again only if the grid is refined
    on_plan = samples_on_plan(near_plan, reduction.cv_x_m, reduction.cv_y_m)
    if not (reduction.support & mask).any() or on_plan < MIN_SAMPLES_ON_PLAN:
        raise BuildError(
            f"floor {floor}: {'none' if on_plan == 0 else f'only {100 * on_plan:.0f} %'} of "
            f"the {reduction.n_samples} samples of its {len(field_walks)} walks lie within "
            f"{ON_PLAN_M:g} m of the plan's reachable area (is the plan this floor's, whole, "
            "and in the walks' frame, in metres?)")
    raster_params, heading_params, smoothing_scores = params.raster, params.heading_raster, {}
    if params.auto_bandwidth and params.raster.kernel_based:
        say(f"{floor}: cross-validating the smoothing over walks")
        raster_params, smoothing_scores = choose_smoothing(
            grid, mask, reduction.cv_x_m, reduction.cv_y_m, reduction.cv_strength_ut,
            reduction.cv_walk, params.raster, subsample=1)
        bw = raster_params.bandwidth_m
        say(f"{floor}: {raster_params.describe()}, chosen by 5-fold cross-validation "
            "over walks")
        cell_m = raster_cell_m(params, bw)
        fine = None
        if cell_m < grid.cell_m:
            try:
                fine = plan.grid(cell_m)
            except ValueError as err:  # over the grid cap
                say(f"{floor}: kept {grid.cell_m:g} m cells for a {bw:g} m kernel ({err})")
        if fine is not None:
            # a kernel this narrow is judged on cells that resolve it: choose again there
            say(f"{floor}: a {bw:g} m kernel is at most two {grid.cell_m:g} m cells wide; "
                f"rastering on {cell_m:g} m cells instead (BuildParams.min_cell_m) and "
                "cross-validating again there")
            grid = fine
            mask = reachable_mask(grid, plan.reachable)
            near_plan = None
            reduction = reduce_field(store, field_walks, grid, residuals)
            release_free_memory()
            raster_params, smoothing_scores = choose_smoothing(
                grid, mask, reduction.cv_x_m, reduction.cv_y_m, reduction.cv_strength_ut,
                reduction.cv_walk, params.raster, subsample=1,
                candidates=[b for b in BANDWIDTH_CANDIDATES_M if b <= 2 * bw])
            say(f"{floor}: on {cell_m:g} m cells {raster_params.describe()}")
        heading_params = heading_raster_for(params.heading_raster, raster_params.bandwidth_m)
    if residuals is None:
        residuals = empty_residuals()
    layers = {}
    for name, (vals, std) in field_rasters(grid, mask, reduction, raster_params).items():
        unit, kind, desc = FIELD_LAYERS[name]
        layers[name] = Layer(vals, std, unit, kind, desc)
    steps = floor_steps(store, pcat)
    st = steps[np.isfinite(steps["heading_offset_deg"])]
    walk_median = st.groupby("trace_id")["heading_offset_deg"].apply(
        lambda a: circular_median_deg(a.to_numpy()))
    global_offset = float(wrap_deg(circular_median_deg(walk_median.to_numpy()))) \
        if len(walk_median) else 0.0
    local = wrap_deg(st["heading_offset_local_deg"].to_numpy() + global_offset)
    hv, hs = raster(grid, mask, st["x_m"].to_numpy(), st["y_m"].to_numpy(), local,
                    st["trace_id"], heading_params, angle=True)
    layers["heading_offset"] = Layer(
        hv, hs, "deg", "angle", "compass heading minus walking direction: the floor's median "
        "constant plus the spatially varying part; walking direction = compass - offset")
    say(f"{floor}: layers {', '.join(layers)}")
    walks = pcat[["trace_id", "session"]].copy()
    walks["sha256"] = walks["trace_id"].map(cat["sha256"])
    walks["calibration"] = calibration
    walks["heading_offset_median_deg"] = walks["trace_id"].map(walk_median).astype(float)
    walks = walks.sort_values("trace_id").reset_index(drop=True)
    lev = residuals.reset_index().rename(columns={"index": "session"})
    end_ms = float(cat.loc[walks["trace_id"], "end_ms"].max())
    build_time = params.build_time or _time_text(end_ms)
    first = cat.loc[walks["trace_id"].iloc[0]]
    degree = DEGREE.get(raster_params.method, 0)  # 0 also for the Delaunay-linear method
    metrics = {"coverage": coverage(grid, mask, reduction.support), "n_walks": int(len(walks)),
               "samples_on_plan": on_plan,
               "interpolator": raster_params.method,
               "bandwidth_m": raster_params.bandwidth_m, "prior_walks": raster_params.prior_walks,
               "slope_ridge": raster_params.slope_ridge if degree >= 1 else None,
               "curvature_ridge": raster_params.curvature_ridge if degree == 2 else None,
               "smoothing_cv_shape_rmse_ut": {  # inf: a candidate that predicted nothing
                   k: v if np.isfinite(v) else None for k, v in smoothing_scores.items()},
               "n_samples": reduction.n_samples, "heading_offset_floor_median_deg": global_offset}
    if raw.any():  # (only then: the bundles of calibrated surveys keep their bytes)
        metrics["not_calibrated_walks"] = {
            "trace_ids": sorted(pcat.loc[raw, "trace_id"].astype(str)),
            "in_magnetic_layers": not (~raw).any()}
    quality = heldout_quality(grid, mask, reduction.cv_x_m, reduction.cv_y_m,
                              reduction.cv_strength_ut, reduction.cv_walk, raster_params)
    if quality:  # how well the strength layer predicts walks it did not see
        metrics["heldout_strength"] = {k: v if np.isfinite(v) else None
                                       for k, v in quality.items()}
    tables = {"source_walks": pa.Table.from_pandas(walks, preserve_index=False),
              "levelling": pa.Table.from_pandas(lev.astype({"session": "str"}),
                                                preserve_index=False)}
    if params.radio is not None:
        if radio is None:
            radio = build_site_radio(store, [floor], site=site, params=params.radio,
                                     exclude_walks=exclude_walks, progress=say)
        radio = radio.on_plan(floor, near_plan or near_plan_of(grid, mask))
        tables.update(radio.floor_tables(floor))
        metrics["radio"] = radio.floor_metrics(floor)
    return BundleContent(
        site_id=str(first["site_id"] or first["site"]), floor_id=str(first["floor_id"] or floor),
        floor_name=floor, grid=grid, mask=mask, layers=layers,
        tables=tables,
        build={"params": params.to_dict(), "build_time": build_time,
               "data_end_time": _time_text(end_ms), "seed": params.seed,
               "floor_plan": [{"file": name, "sha256": digest}
                              for name, digest in plan.sources],
               "source_walks": [{"trace_id": t, "sha256": h}
                                for t, h in zip(walks["trace_id"], walks["sha256"])]},
        metrics=metrics)
