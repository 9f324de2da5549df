"""Leave-one-walk-out accuracy of magnetic maps on the real traces, against baselines.

    python benchmarks/map_accuracy.py [--floors F1 F2 F3] [--store DIR]

Needs ``../shared/ilc/site1`` (skips cleanly without it). Ingests and processes the floors into
a store (``--store`` to reuse one), then for every floor prints, for strength and the vertical
component: absolute RMSE and median, shape RMSE (each held-out walk's median residual
removed), skill (1 - shape RMSE / constant map's), and the correlation between the map's and the
observed field change along held-out walks over 0.7 m and 5 m. Pipelines: a constant map (floor
mean), linear interpolation on time-interpolated positions without levelling (the baseline of
FINDINGS.md), and indoormap's default. Every held-out walk is positioned from its own data only.
The figures come from ``mapping.holdout`` (what ``indoormap validate`` reports).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

from real_data import ILC_SITE1  # $INDOORMAP_ILC or ../shared/ilc

SITE = ILC_SITE1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--floors", nargs="*", default=["F1", "F2", "F3"])
    ap.add_argument("--store", type=Path, default=None)
    ap.add_argument("--interpolator", default=None,
                    help="indoormap's interpolator (default: the build's default)")
    args = ap.parse_args()
    if not all((SITE / f / "path_data_files").is_dir() for f in args.floors):
        print(f"skipped: {SITE} not available")
        return 0
    from mapping.build import BuildParams, build_smoothing
    from mapping.floorplan import read_floor_plan
    from mapping.grid import reachable_mask
    from mapping.holdout import (
        default_pipelines,
        floor_samples_with_baseline_positions,
        leave_one_walk_out,
    )
    from mapping.interpolate import RasterParams
    from mapping.levelling import apply_session_residuals, fit_session_residuals
    from survey.ingest import ingest
    from survey.process_store import process_store
    from survey.store import SurveyStore

    with tempfile.TemporaryDirectory() as tmp:
        store_dir = args.store or Path(tmp) / "store"
        plans = {f: read_floor_plan(SITE / f) for f in args.floors}
        t = time.perf_counter()
        ingest([SITE / f / "path_data_files" for f in args.floors], store_dir)
        store = SurveyStore.open(store_dir)
        process_store(store, reachable={(s, f): plans[f].reachable for s, f in store.catalog()[
            ["site", "floor"]].drop_duplicates().itertuples(index=False) if f in plans})
        print(f"ingest + process: {time.perf_counter() - t:.0f} s", flush=True)
        pd.set_option("display.width", 200)
        for f in args.floors:
            t = time.perf_counter()
            samples = floor_samples_with_baseline_positions(store, f)
            grid = plans[f].grid(0.5)
            mask = reachable_mask(grid, plans[f].reachable)
            params = BuildParams() if args.interpolator is None else \
                BuildParams(raster=RasterParams(method=args.interpolator))
            levelled = apply_session_residuals(samples, fit_session_residuals(
                samples, params.levelling))
            chosen, _ = build_smoothing(samples, levelled, grid, mask, params)
            table = leave_one_walk_out(samples, grid, mask, default_pipelines(chosen),
                                       layers=("strength", "vertical"))
            print(f"\nsite1/{f}: {samples['trace_id'].nunique()} walks, leave-one-walk-out "
                  f"({time.perf_counter() - t:.0f} s); {chosen.describe()} (chosen by the "
                  "build's 5-fold cross-validation over all walks of the floor)")
            cols = ["layer", "pipeline", "rmse", "median_abs", "shape_rmse", "skill",
                    "corr_0.7m", "corr_5m"]
            print(table[cols].sort_values(["layer", "pipeline"]).to_string(
                index=False, float_format=lambda v: f"{v:.3f}"))
            d = table.set_index(["layer", "pipeline"])
            base = "linear, time-linear positions, no levelling (baseline)"
            ours = "indoormap default"
            vs = d.loc[("vertical", ours), "shape_rmse"] / d.loc[("vertical", base),
                                                                  "shape_rmse"] - 1
            print(f"vertical shape RMSE vs baseline: {100 * vs:+.0f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
