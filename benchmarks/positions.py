"""Survey processing against simulated ground truth: positions, steps, attitude, headings.

    python benchmarks/positions.py [--site DIR] [--seed 11]

Without ``--site`` a site is simulated first (preset ``default``: 3 floors, 48 walks with pauses,
pace changes and several holding modes; about a minute). Prints, over all walks, the position
error of indoormap's default (step-shaped track fitted to the waypoints) and of time-linear
interpolation, in the same run, plus step-count error, attitude accuracy and the error of the
heading-offset samples against the simulated compass deviation.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from survey.field_features import wrap_deg
from survey.positions import time_linear_positions
from survey.process import process_walk
from survey.sim.site import SiteParams, simulate_site
from survey.trace_reader import read_trace

EXPECTED_ATTITUDE = {"flat_forward": "UFH", "upward_not_flat": "UFNH", "swinging": "NU",
                     "pocket": "NU"}


def evaluate(site: Path) -> dict:
    truth = json.loads((site / "truth" / "site.json").read_text())
    err, err_tl, steps, att_ok, att_n, hdg = [], [], [], 0, 0, []
    t0 = time.perf_counter()
    for w in truth["walks"]:
        tr = read_trace(site / w["trace_path"])
        tt = pd.read_parquet(site / w["truth_path"]).set_index("t_ms")
        n_true = len(pd.read_parquet(str(site / w["truth_path"]).replace(".parquet",
                                                                          ".steps.parquet")))
        walk = process_walk(tr.trace_id, tr.sensors, tr.waypoints)
        s = walk.samples
        true_xy = tt.reindex(s["t_ms"])[["x_m", "y_m"]].to_numpy()
        err.append(np.hypot(*(s[["x_m", "y_m"]].to_numpy() - true_xy).T))
        tl = time_linear_positions(tr.waypoints["t_ms"], tr.waypoints[["x_m", "y_m"]], s["t_ms"])
        err_tl.append(np.hypot(*(tl.xy_m - true_xy).T))
        steps.append((walk.summary["n_steps"] - n_true) / n_true)
        near = tt.iloc[tt.index.get_indexer(walk.steps["t_ms"], method="nearest")]
        expected = near["holding_mode"].map(EXPECTED_ATTITUDE).to_numpy()
        att_ok += int((walk.steps["attitude"].to_numpy() == expected).sum())
        att_n += len(expected)
        hdg.append(wrap_deg(walk.steps["heading_offset_deg"].to_numpy()
                            + near["compass_deviation_deg"].to_numpy()))
    e, etl, h = np.concatenate(err), np.concatenate(err_tl), np.concatenate(hdg)
    return {"walks": len(truth["walks"]), "seconds": time.perf_counter() - t0,
            "pos": (np.median(e), np.percentile(e, 80), np.mean(e)),
            "pos_tl": (np.median(etl), np.percentile(etl, 80), np.mean(etl)),
            "steps": (np.mean(np.abs(steps)), np.max(np.abs(steps))),
            "attitude": att_ok / att_n, "heading": np.nanmedian(np.abs(h))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--site", type=Path)
    ap.add_argument("--seed", type=int, default=11)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        site = args.site
        if site is None:
            site = Path(tmp) / "site"
            print(f"simulating preset 'default', seed {args.seed} ...", flush=True)
            simulate_site(SiteParams.preset_params("default", seed=args.seed), site)
        r = evaluate(site)
    print(f"{r['walks']} walks of {site} processed in {r['seconds']:.1f} s")
    print(f"{'positions (m)':<44} {'median':>7} {'p80':>7} {'mean':>7}")
    print(f"{'indoormap default (steps fitted to clicks)':<44} "
          + " ".join(f"{v:7.3f}" for v in r["pos"]))
    print(f"{'time-linear between waypoints (baseline)':<44} "
          + " ".join(f"{v:7.3f}" for v in r["pos_tl"]))
    print(f"ratio of medians (baseline / default): {r['pos_tl'][0] / r['pos'][0]:.2f}")
    print(f"step count error: mean {100 * r['steps'][0]:.2f} %, worst walk "
          f"{100 * r['steps'][1]:.2f} %")
    print(f"attitude class right: {100 * r['attitude']:.1f} % of steps")
    print(f"heading offset vs simulated compass deviation: median abs error "
          f"{r['heading']:.2f} deg")
    return 0


if __name__ == "__main__":
    sys.exit(main())
