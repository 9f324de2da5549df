"""Magnetometer calibration on the real traces: does the chosen calibration make walks agree?

    python benchmarks/calibration.py [FLOOR_DIR ...]

Default: ``../shared/ilc/site1/F1`` (skips cleanly without it). Every walk is processed with
indoormap's default (positions, rotation into the map frame); only the calibration differs:

- chosen: indoormap's decision per walk (the phone's calibrated stream when plausible, ...);
- uncalibrated minus the phone's reported bias;
- naive per-walk sphere fit of the uncalibrated samples (hard iron = fitted centre);
- the chosen calibration with time-linear positions between waypoints (pairs found with those
  positions), to see what the positions contribute.

For pairs of samples from different walks within 0.5 m of each other (at most one pair per
sample), it prints the median absolute and RMS difference of the earth-frame strength and
vertical component. Lower is better: the map merges those walks.

On the simulated sample (``data/sample_site/F1``) the naive sphere fit beats the chosen
calibration (1.7 against 4.3 uT): the simulated phones report their hard iron with a residual
of a few uT per calibration session on purpose (`survey.sim.devices.make_sessions`; what the
build's levelling removes before the maps, not in this comparison), while a simulated walk's
raw field, a known soft iron and hard iron applied to the true field, is what a sphere fit
recovers. The comparison is meant for real traces.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from survey.field_features import field_features
from survey.magcal import fit_sphere
from survey.positions import time_linear_positions
from survey.process import process_walk
from survey.rotation import interpolate_rotation_vector, rotation_matrices
from survey.trace_reader import ReadFailure, find_trace_files, iter_traces

from real_data import ILC_SITE1  # $INDOORMAP_ILC or ../shared/ilc

DEFAULT = ILC_SITE1 / "F1"


def earth(trace, t_ms, device_field):
    rv = trace.stream("rotation_vector")
    q = interpolate_rotation_vector(rv["t_ms"].to_numpy(float), rv[["x", "y", "z"]].to_numpy(float),
                                    t_ms.astype(float))
    return np.einsum("nij,nj->ni", rotation_matrices(q, quaternion=True), device_field)


def cross_walk_pairs(frame: pd.DataFrame, radius_m: float = 0.5, cols=("x_m", "y_m")
                     ) -> tuple[np.ndarray, np.ndarray]:
    xy = frame[list(cols)].to_numpy()
    tree = cKDTree(xy)
    d, j = tree.query(xy, k=16, distance_upper_bound=radius_m)
    walk = frame["walk"].to_numpy()
    i_idx, j_idx = [], []
    for col in range(1, d.shape[1]):
        ok = np.isfinite(d[:, col])
        jj = np.where(ok, j[:, col], 0)
        other = ok & (walk[jj] != walk)
        i_idx.append(np.flatnonzero(other))
        j_idx.append(jj[other])
    i_all, j_all = np.concatenate(i_idx), np.concatenate(j_idx)
    first = np.unique(i_all, return_index=True)[1]  # one partner per sample
    return i_all[first], j_all[first]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("floors", nargs="*", type=Path, default=[DEFAULT], metavar="FLOOR_DIR",
                    help=f"floor folders (default {DEFAULT})")
    floors = ap.parse_args().floors
    if not all((f / "path_data_files").is_dir() for f in floors):
        print(f"skipped: {', '.join(map(str, floors))} not available")
        return 0
    for floor in floors:
        rows = []
        for i, tr in enumerate(iter_traces(find_trace_files([floor / "path_data_files"]))):
            if isinstance(tr, ReadFailure):
                print(f"skipped {tr.path}: {tr.error}", file=sys.stderr)
                continue
            walk = process_walk(tr.trace_id, tr.sensors, tr.waypoints)
            s = walk.samples
            unc = tr.stream("magnetic_field_uncalibrated").set_index("t_ms").reindex(s["t_ms"])
            raw = unc[["x", "y", "z"]].to_numpy(float)
            bias = unc[["bx", "by", "bz"]].to_numpy(float)
            sphere = fit_sphere(raw[np.isfinite(raw).all(axis=1)])
            t = s["t_ms"].to_numpy()
            variants = {
                "chosen": s[["mag_east_ut", "mag_north_ut", "mag_up_ut"]].to_numpy(),
                "uncalibrated - reported bias": earth(tr, t, raw - bias),
                "naive per-walk sphere fit": earth(tr, t, raw - sphere.hard_iron_ut),
            }
            tl = time_linear_positions(tr.waypoints["t_ms"], tr.waypoints[["x_m", "y_m"]], t)
            frame = pd.DataFrame({"walk": i, "x_m": s["x_m"], "y_m": s["y_m"],
                                  "tl_x_m": tl.xy_m[:, 0], "tl_y_m": tl.xy_m[:, 1]})
            for name, e in variants.items():
                f = field_features(e)
                frame[f"{name}|strength"] = f.strength_ut
                frame[f"{name}|vertical"] = f.vertical_ut
            frame["decision"] = walk.summary["calibration"]
            rows.append(frame[::5])  # ~10 Hz is plenty for 0.5 m pairs
        data = pd.concat(rows, ignore_index=True).dropna()
        i, j = cross_walk_pairs(data)
        decisions = data.groupby("walk")["decision"].first().value_counts().to_dict()
        print(f"{floor}: {data['walk'].nunique()} walks, {len(i)} cross-walk pairs within 0.5 m;"
              f" decisions {decisions}")
        print(f"{'calibration':<32} {'strength med':>12} {'RMS':>7} {'vertical med':>13} {'RMS':>7}"
              "   (uT)")
        ti, tj = cross_walk_pairs(data, cols=("tl_x_m", "tl_y_m"))
        for name, (pi, pj) in (("chosen", (i, j)),
                               ("uncalibrated - reported bias", (i, j)),
                               ("naive per-walk sphere fit", (i, j)),
                               ("chosen, time-linear positions", (ti, tj))):
            col = name.split(",")[0]
            ds = data[f"{col}|strength"].to_numpy()
            dv = data[f"{col}|vertical"].to_numpy()
            a, b = ds[pi] - ds[pj], dv[pi] - dv[pj]
            print(f"{name:<32} {np.median(np.abs(a)):12.2f} {np.sqrt(np.mean(a * a)):7.2f} "
                  f"{np.median(np.abs(b)):13.2f} {np.sqrt(np.mean(b * b)):7.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
