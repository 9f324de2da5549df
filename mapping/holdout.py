"""Held-out accuracy of magnetic maps: leave one walk out, predict it, compare.

One implementation for ``benchmarks/map_accuracy.py`` and ``indoormap validate``.

For every walk of a floor, the map is built from all other walks (cell statistics are sums, so
"all minus one" is a subtraction) and sampled at the held-out walk's own positions, which come
from that walk's data only (its waypoints and sensors). Levelling is fitted per group of walks
(``levelling_folds`` groups) on the walks outside the group, so it never sees the walk it is
scored on either.

Metrics per layer, over all held-out samples of the floor:

- ``rmse``, ``median_abs``: absolute errors (uT);
- ``shape_rmse``: RMSE after removing each held-out walk's median residual;
- ``skill``: ``1 - shape_rmse / shape_rmse(constant map)``;
- ``corr_0.7m``, ``corr_5m``: Pearson correlation between the map's and the observed change of
  the value along the held-out walk over 0.7 m and 5 m of track (samples every 0.7 m).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from localize.bundle import Grid, sample_grid

from .interpolate import CellStats, RasterParams, cell_stats, raster_from_stats, \
    walk_cell_means
from .levelling import LevellingParams, apply_session_residuals, fit_session_residuals

LAYER_COLUMNS = {"strength": "strength_ut", "horizontal": "horizontal_ut",
                 "vertical": "vertical_ut"}
TRACK_STEP_M = 0.7


@dataclass(frozen=True)
class Pipeline:
    """How a map is made: which positions, whether to level, which interpolator."""

    name: str
    positions: str = "steps"  # "steps" (the processed track) or "time" (time-linear)
    level: bool = True
    raster: RasterParams = RasterParams()
    constant: bool = False  # the map is the floor mean everywhere


def layer_values(samples: pd.DataFrame, field_enu: NDArray) -> dict[str, NDArray]:
    e, n, u = field_enu.T
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
    """Metrics from a list of (observed, predicted, x, y) per held-out walk (map-only)."""
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
        return {}
    o, p, sr = np.concatenate(obs), np.concatenate(pred), np.concatenate(shape_res)

    def corr(a, b):
        a, b = np.concatenate(a), np.concatenate(b)
        if len(a) < 3 or np.std(a) == 0 or np.std(b) == 0:
            return float("nan")
        return float(np.corrcoef(a, b)[0, 1])

    return {"rmse": float(np.sqrt(np.mean((p - o) ** 2))),
            "median_abs": float(np.median(np.abs(p - o))),
            "shape_rmse": float(np.sqrt(np.mean(sr * sr))),
            "corr_0.7m": corr(d07_p, d07_o), "corr_5m": corr(d5_p, d5_o),
            "n_samples": int(len(o)), "n_walks": len(obs)}


def leave_one_walk_out(samples: pd.DataFrame, grid: Grid, mask: NDArray[np.bool_],
                       pipelines: list[Pipeline], *, layers=("strength", "vertical"),
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

    Returns
    -------
    DataFrame with one row per (pipeline, layer) and the columns of :func:`metrics` plus
    ``skill`` (relative to the constant map of the same layer).
    """
    s = samples.iloc[::subsample].reset_index(drop=True)
    walks = np.asarray(sorted(s["trace_id"].unique()))
    walk_code = np.searchsorted(walks, s["trace_id"].to_numpy())
    raw_field = s[["mag_east_ut", "mag_north_ut", "mag_up_ut"]].to_numpy(np.float64)
    fold_of_walk = np.arange(len(walks)) % max(1, levelling_folds)
    rows = []
    for pipe in pipelines:
        px, py = (("x_m", "y_m") if pipe.positions == "steps" else ("tl_x_m", "tl_y_m"))
        x, y = s[px].to_numpy(), s[py].to_numpy()
        results: dict[str, list] = {layer: [] for layer in layers}
        for fold in range(max(1, levelling_folds) if pipe.level else 1):
            if pipe.level:
                train = ~np.isin(walk_code, np.flatnonzero(fold_of_walk == fold))
                resid = fit_session_residuals(s[train], levelling)
                field = apply_session_residuals(s, resid)
                fold_walks = np.flatnonzero(fold_of_walk == fold)
            else:
                field = raw_field
                fold_walks = np.arange(len(walks))
            values = layer_values(s, field)
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
                        vals, _ = raster_from_stats(grid, mask, stats, pipe.raster)
                        pred = sample_grid(grid, mask, vals, x[sel], y[sel])
                    results[layer].append((obs, pred, x[sel], y[sel]))
            if progress:
                progress(f"{pipe.name}: fold {fold + 1}")
        for layer in layers:
            rows.append({"pipeline": pipe.name, "layer": layer, **metrics(results[layer])})
    table = pd.DataFrame(rows)
    const = table[table["pipeline"] == next((p.name for p in pipelines if p.constant), "")]
    base = dict(zip(const["layer"], const["shape_rmse"])) if len(const) else {}
    table["skill"] = [1 - r.shape_rmse / base[r.layer] if r.layer in base else np.nan
                      for r in table.itertuples()]
    return table
