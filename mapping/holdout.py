"""Held-out accuracy of magnetic maps: leave one walk out, predict it, compare.

One implementation for ``benchmarks/map_accuracy.py`` and ``indoormap validate``.

For every walk of a floor, the map is built from all other walks (cell statistics are sums, so
"all minus one" is a subtraction) and sampled at the held-out walk's own positions, which come
from that walk's data only (its waypoints and sensors). Levelling is fitted per group of walks
(``levelling_folds`` groups) on the walks outside the group, so it never sees the walk it is
scored on either.

Metrics per layer, over the held-out samples that every compared pipeline predicts (a map is
NaN far from its support; ``coverage`` reports the share each pipeline predicts):

- ``rmse``, ``median_abs``: absolute errors (uT);
- ``shape_rmse``: RMSE after removing each held-out walk's median residual;
- ``skill``: ``1 - shape_rmse / shape_rmse(constant map)``;
- ``corr_0.7m``, ``corr_5m``: Pearson correlation between the map's and the observed change of
  the value along the held-out walk over 0.7 m and 5 m of track (samples every 0.7 m).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from itertools import product
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from localize.bundle import BilinearLookup, Grid, sample_grid

from .interpolate import (
    DEGREE,
    CellStats,
    RasterParams,
    cell_stats,
    kernel_mean,
    kernel_sums,
    prior_of,
    raster_from_stats,
    walk_cell_means,
)
from .levelling import LevellingParams, apply_session_residuals, fit_session_residuals

if TYPE_CHECKING:  # an annotation only
    from survey.store import SurveyStore

TRACK_STEP_M = 0.7


@dataclass(frozen=True)
class Pipeline:
    """How a map is made: which positions, whether to level, which interpolator."""

    name: str
    positions: str = "steps"  # "steps" (the processed track) or "time" (time-linear)
    level: bool = True
    raster: RasterParams = RasterParams()
    constant: bool = False  # the map is the floor mean everywhere


def layer_values(field_enu: NDArray) -> dict[str, NDArray]:
    """Strength, horizontal and vertical component (uT) per sample of the map-frame field
    (n, 3: east, north, up; uT)."""
    e, n, u = np.asarray(field_enu, dtype=np.float64).T
    return {"strength": np.sqrt(e * e + n * n + u * u), "horizontal": np.hypot(e, n),
            "vertical": u}


def _track_resample(x: NDArray, y: NDArray, series: list[NDArray]) -> list[NDArray]:
    d = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])
    keep = np.concatenate([[True], np.diff(d) > 0])
    if keep.sum() < 2:
        return [np.empty(0) for _ in series]
    at = np.arange(0.0, d[keep][-1], TRACK_STEP_M)
    return [np.interp(at, d[keep], s[keep]) for s in series]


def metrics(per_walk: list[tuple[NDArray, NDArray, NDArray, NDArray]]) -> dict[str, float]:
    """Metrics from a list of (observed, predicted, x, y) per held-out walk (map-only). NaN
    (and counts of 0) when no walk has 5 predicted samples."""
    obs, pred, shape_res, d07_o, d07_p, d5_o, d5_p = [], [], [], [], [], [], []
    lag5 = int(round(5.0 / TRACK_STEP_M))
    for o, p, x, y in per_walk:
        ok = np.isfinite(o) & np.isfinite(p)
        if ok.sum() < 5:
            continue
        o, p, x, y = o[ok], p[ok], x[ok], y[ok]
        obs.append(o)
        pred.append(p)
        r = p - o
        shape_res.append(r - np.median(r))
        ro, rp = _track_resample(x, y, [o, p])
        if len(ro) > lag5:
            d07_o.append(ro[1:] - ro[:-1])
            d07_p.append(rp[1:] - rp[:-1])
            d5_o.append(ro[lag5:] - ro[:-lag5])
            d5_p.append(rp[lag5:] - rp[:-lag5])
    if not obs:
        nan = float("nan")
        return {"rmse": nan, "median_abs": nan, "shape_rmse": nan, "corr_0.7m": nan,
                "corr_5m": nan, "n_samples": 0, "n_walks": 0}
    o, p, sr = np.concatenate(obs), np.concatenate(pred), np.concatenate(shape_res)

    def corr(a: list[NDArray], b: list[NDArray]) -> float:
        if not a:  # no walk covers the span
            return float("nan")
        a, b = np.concatenate(a), np.concatenate(b)
        if len(a) < 3 or np.std(a) == 0 or np.std(b) == 0:
            return float("nan")
        return float(np.corrcoef(a, b)[0, 1])

    return {"rmse": float(np.sqrt(np.mean((p - o) ** 2))),
            "median_abs": float(np.median(np.abs(p - o))),
            "shape_rmse": float(np.sqrt(np.mean(sr * sr))),
            "corr_0.7m": corr(d07_p, d07_o), "corr_5m": corr(d5_p, d5_o),
            "n_samples": int(len(o)), "n_walks": len(obs)}


def _predict_windowed(grid: Grid, mask: NDArray[np.bool_], stats: CellStats,
                      params: RasterParams, x: NDArray, y: NDArray) -> NDArray:
    """Raster values at points, computing the raster only in a window around them.

    The window is padded by the kernel's reach (3 bandwidths) plus the maximum distance to
    support plus a margin, and the smoother's prior is the whole floor's, so kernel values
    inside equal the whole-floor raster's. The linear baseline's Delaunay triangles near the
    window edge can differ (by up to ~0.1 of the value range in a test)."""
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any():
        return np.full(len(x), np.nan)
    pad = 3 * params.bandwidth_m + params.max_distance_m + 2 * grid.cell_m
    if params.method == "linear":
        pad = max(pad, 10.0)
    c0 = max(int(np.floor((x[ok].min() - pad - grid.x0_m) / grid.cell_m)), 0)
    c1 = min(int(np.ceil((x[ok].max() + pad - grid.x0_m) / grid.cell_m)), grid.width)
    r0 = max(int(np.floor((y[ok].min() - pad - grid.y0_m) / grid.cell_m)), 0)
    r1 = min(int(np.ceil((y[ok].max() + pad - grid.y0_m) / grid.cell_m)), grid.height)
    if c1 <= c0 or r1 <= r0:
        return np.full(len(x), np.nan)
    sub = Grid(grid.x0_m + c0 * grid.cell_m, grid.y0_m + r0 * grid.cell_m, grid.cell_m,
               c1 - c0, r1 - r0)
    win = (slice(r0, r1), slice(c0, c1))
    vals, _ = raster_from_stats(sub, mask[win], CellStats(stats.n[win], stats.s[win],
                                                          stats.q[win]), params,
                                prior=prior_of(stats))
    return sample_grid(sub, mask[win], vals, x, y)


def leave_one_walk_out(samples: pd.DataFrame, grid: Grid, mask: NDArray[np.bool_],
                       pipelines: list[Pipeline], *,
                       layers: Sequence[str] = ("strength", "vertical"),
                       levelling: LevellingParams = LevellingParams(),
                       levelling_folds: int = 10, subsample: int = 5,
                       progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """Leave-one-walk-out metrics for each pipeline and layer.

    Parameters
    ----------
    samples : DataFrame
        Processed samples of one floor with ``trace_id``, ``session``, ``x_m``, ``y_m`` (the
        step track), ``tl_x_m``, ``tl_y_m`` (time-linear positions, for pipelines using them),
        the map-frame field ``mag_*_ut`` and the attitude quaternion ``q_*``.
    subsample : int
        Use every n-th sample (50 Hz is far denser than the field varies along a track).
    levelling : LevellingParams
        As the build's. Its ``subsample`` counts the floor's samples, as in the build: the
        levelling is fitted on every ``max(1, levelling.subsample // subsample)``-th of the
        thinned samples, i.e. on every ``levelling.subsample``-th sample of the floor when
        ``subsample`` divides it (the defaults, 5 and 5), as the build does.

    Returns
    -------
    DataFrame with one row per (pipeline, layer) and the columns of :func:`metrics` plus
    ``skill`` (relative to the constant map of the same layer).
    """
    s = samples.iloc[::subsample].reset_index(drop=True)
    # the build levels on every levelling.subsample-th sample of the floor: so does this
    levelling = replace(levelling, subsample=max(1, levelling.subsample // subsample))
    walks = np.asarray(sorted(s["trace_id"].unique()))
    walk_code = np.searchsorted(walks, s["trace_id"].to_numpy())
    raw_field = s[["mag_east_ut", "mag_north_ut", "mag_up_ut"]].to_numpy(np.float64)
    n_folds = max(1, min(levelling_folds, len(walks)))  # no empty folds with few walks
    fold_of_walk = np.arange(len(walks)) % n_folds
    levelled: dict[tuple[str, int], NDArray] = {}
    collected: dict[tuple[str, str], tuple[NDArray, NDArray, NDArray, NDArray]] = {}
    for pipe in pipelines:
        px, py = (("x_m", "y_m") if pipe.positions == "steps" else ("tl_x_m", "tl_y_m"))
        x, y = s[px].to_numpy(), s[py].to_numpy()
        pred_of = {layer: np.full(len(s), np.nan) for layer in layers}
        obs_of = {layer: np.full(len(s), np.nan) for layer in layers}
        for fold in range(n_folds if pipe.level else 1):
            if pipe.level:
                if (pipe.positions, fold) not in levelled:
                    train = ~np.isin(walk_code, np.flatnonzero(fold_of_walk == fold))
                    train_s = s[train].assign(x_m=x[train], y_m=y[train])
                    levelled[(pipe.positions, fold)] = apply_session_residuals(
                        s, fit_session_residuals(train_s, levelling))
                field = levelled[(pipe.positions, fold)]
                fold_walks = np.flatnonzero(fold_of_walk == fold)
            else:
                field = raw_field
                fold_walks = np.arange(len(walks))
            values = layer_values(field)
            for layer in layers:
                w, cell, mean = walk_cell_means(grid, x, y, values[layer], walk_code)
                total = cell_stats(grid, cell, mean)
                for k in fold_walks:
                    mine = w == k
                    stats: CellStats = total - cell_stats(grid, cell[mine], mean[mine])
                    sel = walk_code == k
                    obs = values[layer][sel]
                    if pipe.constant:
                        pred = np.full(sel.sum(), stats.s.sum() / max(stats.n.sum(), 1))
                    else:
                        pred = _predict_windowed(grid, mask, stats, pipe.raster, x[sel], y[sel])
                    pred_of[layer][sel] = pred
                    obs_of[layer][sel] = obs
            if progress:
                progress(f"{pipe.name}: fold {fold + 1}")
        for layer in layers:
            collected[(pipe.name, layer)] = (obs_of[layer], pred_of[layer], x, y)
    rows = []
    for layer in layers:
        # every pipeline is scored on the samples that all of them predict
        common = np.ones(len(s), dtype=bool)
        for pipe in pipelines:
            common &= np.isfinite(collected[(pipe.name, layer)][1])
        for pipe in pipelines:
            obs, pred, x, y = collected[(pipe.name, layer)]
            per_walk = [(obs[sel], pred[sel], x[sel], y[sel])
                        for sel in (common & (walk_code == k) for k in range(len(walks)))]
            rows.append({"pipeline": pipe.name, "layer": layer, **metrics(per_walk),
                         "coverage": float(np.isfinite(pred).mean())})
    table = pd.DataFrame(rows)
    const = table[table["pipeline"] == next((p.name for p in pipelines if p.constant), "")]
    base = dict(zip(const["layer"], const["shape_rmse"])) if len(const) else {}
    table["skill"] = [1 - r.shape_rmse / base[r.layer] if r.layer in base else np.nan
                      for r in table.itertuples()]
    return table


def floor_samples_with_baseline_positions(store: SurveyStore, floor: str, site: str | None = None
                                          ) -> pd.DataFrame:
    """Processed samples of a floor with their session and also their time-linear positions
    (``tl_x_m``, ``tl_y_m``) for the baseline pipeline."""
    from survey.positions import time_linear_positions

    from .build import floor_samples

    samples = floor_samples(store, site, floor)
    waypoints = store.table("waypoints", site=site, floor=floor)
    by_walk = waypoints.groupby("trace_id")
    tl = np.full((len(samples), 2), np.nan)
    for tid, idx in samples.groupby("trace_id").indices.items():
        w = by_walk.get_group(tid)
        tl[idx] = time_linear_positions(w["t_ms"], w[["x_m", "y_m"]],
                                        samples["t_ms"].to_numpy()[idx]).xy_m
    samples["tl_x_m"], samples["tl_y_m"] = tl[:, 0], tl[:, 1]
    return samples


def default_pipelines(raster: RasterParams = RasterParams()) -> list[Pipeline]:
    """The pipelines every report compares: constant map, the plain-interpolation baseline,
    and indoormap's default."""
    return [
        Pipeline("constant map (floor mean)", positions="steps", level=False, constant=True),
        Pipeline("linear, time-linear positions, no levelling (baseline)", positions="time",
                 level=False, raster=RasterParams(method="linear",
                                                  max_distance_m=raster.max_distance_m)),
        Pipeline("indoormap default", positions="steps", level=True, raster=raster),
    ]


BANDWIDTH_CANDIDATES_M = (0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0)
#: shrinkage towards the floor mean (``RasterParams.prior_walks``) tried with every bandwidth
PRIOR_WALKS_CANDIDATES = (0.1, 0.5, 2.0, 8.0)
#: slope ridges (``RasterParams.slope_ridge``) tried with every pair for ``local_linear``
SLOPE_RIDGE_CANDIDATES = (0.1, 1.0, 10.0, 100.0)
#: curvature ridges (``RasterParams.curvature_ridge``) tried with every triple for
#: ``local_quadratic``; ``inf`` is the local plane, so the cross-validation chooses the degree
CURVATURE_RIDGE_CANDIDATES = (0.1, 1.0, 10.0, 100.0, math.inf)
#: the cross-validation uses every n-th sample (the build takes the same ones)
BANDWIDTH_SUBSAMPLE = 5


def choose_smoothing(grid: Grid, mask: NDArray[np.bool_], x: NDArray, y: NDArray,
                     values: NDArray, walk: NDArray, base: RasterParams, *,
                     candidates: Sequence[float] = BANDWIDTH_CANDIDATES_M,
                     prior_candidates: Sequence[float] = PRIOR_WALKS_CANDIDATES,
                     ridge_candidates: Sequence[float] = SLOPE_RIDGE_CANDIDATES,
                     curvature_candidates: Sequence[float] = CURVATURE_RIDGE_CANDIDATES,
                     folds: int = 5,
                     subsample: int = BANDWIDTH_SUBSAMPLE
                     ) -> tuple[RasterParams, dict[str, float]]:
    """Kernel bandwidth (m), shrinkage (``prior_walks``) and, for a local polynomial, slope
    ridge (and curvature ridge) with the lowest grouped k-fold shape RMSE (uT; folds of whole
    walks).

    How much to smooth depends on how well the survey was positioned and how consistent the
    walks are (sub-metre bandwidth and almost no shrinkage on clean simulated walks, 3 m and
    strong shrinkage on the real traces), so it is measured, not assumed. Returns ``base``
    (a kernel method) with the chosen ``bandwidth_m``, ``prior_walks``, ``slope_ridge`` and
    ``curvature_ridge`` (``local_quadratic`` becomes ``local_linear`` where the plane, an
    infinite curvature ridge, scores best), and the score of every candidate, keyed
    ``"<bandwidth_m>/<prior_walks>[/<slope_ridge>[/<curvature_ridge>]]"`` (the parameters the
    method has).
    """
    if not base.kernel_based:
        raise ValueError(f"choose_smoothing: {base.method!r} has no bandwidth to choose")
    degree = DEGREE[base.method]
    ridges = tuple(ridge_candidates) if degree >= 1 else (None,)
    curvatures = tuple(curvature_candidates) if degree == 2 else (None,)
    x, y, values = x[::subsample], y[::subsample], values[::subsample]
    cv = _WalkFolds.of(grid, mask, x, y, values, walk[::subsample], folds)
    if cv is None:
        return base, {}
    walk_code, train, held_out, lookups = cv.walk_code, cv.train, cv.held_out, cv.lookups
    n_folds = len(train)
    keys = list(product(candidates, prior_candidates, ridges, curvatures))
    per_bandwidth = len(keys) // len(candidates)  # keys run bandwidth-major
    squares, counts = np.zeros(len(keys)), np.zeros(len(keys))
    for b, bw in enumerate(candidates):
        rows = slice(b * per_bandwidth, (b + 1) * per_bandwidth)
        for g in range(n_folds):
            sums = kernel_sums(grid, mask, train[g], bw, base.max_distance_m, degree=degree,
                               cells=lookups[g].cells(grid))
            mu = prior_of(train[g])[0]
            sel = held_out[g]
            residuals = np.empty((per_bandwidth, int(sel.sum())))
            for i, (pw, ridge, curv) in enumerate(product(prior_candidates, ridges,
                                                          curvatures)):
                residuals[i] = lookups[g](kernel_mean(sums, pw, mu, ridge, curv or 0.0)) \
                    - values[sel]
            # a walk is held out in one fold only: its median residual is that fold's
            sq, n = _centred_squares(residuals, walk_code[sel])
            squares[rows] += sq
            counts[rows] += n
    scores = dict(zip(keys, np.where(counts > 0, np.sqrt(squares / np.maximum(counts, 1)),
                                     np.inf)))
    # ties go to the smoother map (larger bandwidth, more shrinkage, flatter fit)
    bw, pw, ridge, curv = min(keys, key=lambda k: (scores[k], -k[0], -k[1],
                                                   *(-(v or 0.0) for v in k[2:])))
    chosen = replace(base, bandwidth_m=bw, prior_walks=pw)
    if ridge is not None:
        chosen = replace(chosen, slope_ridge=ridge)
    if curv is not None:
        chosen = replace(chosen, method="local_linear") if math.isinf(curv) else \
            replace(chosen, curvature_ridge=curv)
    return chosen, {"/".join(f"{v:g}" for v in k if v is not None): float(s)
                    for k, s in scores.items()}


@dataclass
class _WalkFolds:
    """Grouped k-fold over walks of one floor's samples: the cell statistics without each
    fold's walks, and the lookups at that fold's samples."""

    walk_code: NDArray[np.int64]  # rank of each sample's walk
    train: list[CellStats]
    held_out: list[NDArray[np.bool_]]  # per fold, its samples
    lookups: list[BilinearLookup]

    @classmethod
    def of(cls, grid: Grid, mask: NDArray[np.bool_], x: NDArray, y: NDArray, values: NDArray,
           walk: NDArray, folds: int) -> _WalkFolds | None:
        """The folds (walk ``i`` in fold ``i % folds``); None with fewer than 3 walks."""
        walk_code = np.unique(np.asarray(walk), return_inverse=True)[1]
        n_walks = walk_code.max() + 1 if len(walk_code) else 0
        if n_walks < 3:
            return None
        w, cell, mean = walk_cell_means(grid, x, y, values, walk_code)
        total = cell_stats(grid, cell, mean)
        n_folds = min(folds, n_walks)
        group = np.arange(n_walks) % n_folds
        fold_of_pair = group[w]
        train = [total - cell_stats(grid, cell[fold_of_pair == g], mean[fold_of_pair == g])
                 for g in range(n_folds)]
        held_out = [group[walk_code] == g for g in range(n_folds)]
        lookups = [BilinearLookup.at(grid, mask, x[sel], y[sel]) for sel in held_out]
        return cls(walk_code, train, held_out, lookups)


def heldout_quality(grid: Grid, mask: NDArray[np.bool_], x: NDArray, y: NDArray,
                    values: NDArray, walk: NDArray, params: RasterParams, *, folds: int = 5
                    ) -> dict[str, float]:
    """How well a map made with ``params`` predicts walks it did not see: grouped k-fold over
    walks (the folds of :func:`choose_smoothing`), scored as :func:`metrics` does.

    ``x``, ``y`` (m), ``values`` (uT, e.g. the levelled strength) and ``walk`` are per sample,
    each walk's samples together and in time order (the changes along a walk are taken in
    that order). Returns ``shape_rmse_ut``, ``constant_shape_rmse_ut`` (a map of one value:
    each walk's own median removed), ``skill`` (``1 - shape_rmse / constant``),
    ``corr_0.7m``, ``corr_5m`` (map against observed change along the held-out walks; NaN
    when no held-out walk spans the distance), ``n_samples`` (held-out samples predicted),
    ``n_walks`` and ``folds``; empty with fewer than 3 walks or a method without a kernel.
    """
    if not params.kernel_based:
        return {}
    cv = _WalkFolds.of(grid, mask, x, y, values, walk, folds)
    if cv is None:
        return {}
    degree = DEGREE[params.method]
    pred = np.full(len(values), np.nan)
    for g, sel in enumerate(cv.held_out):
        sums = kernel_sums(grid, mask, cv.train[g], params.bandwidth_m, params.max_distance_m,
                           degree=degree, cells=cv.lookups[g].cells(grid))
        mean = kernel_mean(sums, params.prior_walks, prior_of(cv.train[g])[0],
                           params.slope_ridge if degree >= 1 else None,
                           params.curvature_ridge if degree == 2 else 0.0)
        pred[sel] = cv.lookups[g](mean)
    n_walks = int(cv.walk_code.max()) + 1
    starts = np.flatnonzero(np.r_[True, np.diff(cv.walk_code) != 0])
    per_walk = [(values[a:b], pred[a:b], x[a:b], y[a:b])
                for a, b in zip(starts, np.r_[starts[1:], len(values)])]
    got = metrics(per_walk)
    if not got["n_walks"]:
        return {}
    ok = np.isfinite(pred) & np.isfinite(values)
    centred = [v[k] - np.median(v[k]) for v, p, _, _ in per_walk
               for k in [np.isfinite(v) & np.isfinite(p)] if k.sum() >= 5]
    constant = float(np.sqrt(np.mean(np.concatenate(centred) ** 2)))
    return {"shape_rmse_ut": got["shape_rmse"], "constant_shape_rmse_ut": constant,
            "skill": 1.0 - got["shape_rmse"] / constant if constant > 0 else float("nan"),
            "corr_0.7m": got["corr_0.7m"], "corr_5m": got["corr_5m"],
            "n_samples": int(ok.sum()), "n_walks": n_walks, "folds": len(cv.train)}


def _centred_squares(residuals: NDArray[np.float64], walk: NDArray[np.int64]
                     ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Per row of ``residuals`` (candidates x points, NaN = not predicted): the sum of squares
    after each walk's median residual is removed, and the count of values (the shape RMSE is
    the root of their ratio)."""
    some = np.isfinite(residuals).any(axis=0)  # points no candidate predicts count nowhere
    order = np.argsort(walk[some], kind="stable")
    r = residuals[:, some][:, order]
    bounds = np.flatnonzero(np.diff(walk[some][order])) + 1
    centred = np.empty_like(r)
    for start, stop in zip(np.r_[0, bounds], np.r_[bounds, r.shape[1]]):
        part = r[:, start:stop]
        if part.shape[1] and np.isfinite(part).all():
            centred[:, start:stop] = part - np.median(part, axis=1, keepdims=True)
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a walk with no value in a row
            centred[:, start:stop] = part - np.nanmedian(part, axis=1, keepdims=True)
    return np.nansum(centred ** 2, axis=1), np.isfinite(centred).sum(axis=1)
