"""Wi-Fi fingerprint accuracy on the real traces: positions, floors, cross-device calibration.

    python benchmarks/wifi_accuracy.py [--store DIR] [--folds N] [--floors F1,F2,F3]

Data: ``../shared/ilc/site1/F1..F3`` (skips cleanly without it), ingested and processed once
into ``--store`` (default ``/tmp/indoormap-wifi-bench``; reused when present). Truth = the
processed scan positions (waypoint-fitted walk positions at scan time).

Positions, per floor, leave-one-walk-out (``--folds 0``, default) or grouped k-fold by walk:

- ``baseline``: plain kNN over raw scans: every training scan is a reference, k = 5, plain mean,
  Euclidean distance in dBm, not heard = -100 dBm, rows of any age;
- ``baseline 3s``: the same with rows older than 3 s dropped on both sides;
- ``scans+sorensen`` (``--with-scans``): indoormap's matcher over raw scans (no grid);
- ``default``: indoormap's default: 1 m reference-point grid, rows up to 6 s, Sorensen kNN on
  powed RSSI (k = 5, 1/d^2), query rows older than 2.5 s down-weighted;
- ``gaussian``: the probabilistic match on the same grid.

Floors: logistic regression on transmitter presence, grouped 10-fold by walk over the three
floors: accuracy per scan, per 5-scan sequence and per walk.

Device calibration: every held-out walk's RSSI is mapped through ``0.85 * rssi - 8`` and,
harsher, ``rssi - 12`` (phones that report weaker values). Without calibration the walk is
matched as is; with calibration, ``localize.rssi_calibration`` estimates ``(k, b)`` from the
walk's first 8 scans (rows <= 3 s) and the whole walk is calibrated. Reported: median error
and its loss against the untransformed walks (target < 10 %), and how close the combined map
(transform then calibration) comes to the identity.

Runtime: leave-one-walk-out over the three floors takes about 20 min on 2 cores
(``--folds 10``: about 2 min).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from localize.rssi_calibration import estimate_rssi_calibration
from mapping.fingerprints import build_fingerprints
from mapping.floor_model import cross_validate_floor_model
from mapping.matching import GaussianMatch, WeightedKNN, align_scans, default_matcher
from mapping.radio_scans import ScanSet, scan_set, wifi_observations
from survey.ingest import ingest
from survey.process_store import process_store, processed_table

REPO = Path(__file__).resolve().parents[1]
SITE = REPO.parent / "shared" / "ilc" / "site1"
TRANSFORMS = ((0.85, -8.0), (1.0, -12.0))
CAL_SCANS = 8


def prepare_store(store: Path, floors: list[str]) -> None:
    if (store / "processed" / "catalog.parquet").exists():
        return
    t = time.time()
    ingest([SITE / f / "path_data_files" for f in floors], store)
    process_store(store)
    print(f"(ingested and processed {', '.join(floors)} into {store} in {time.time() - t:.0f} s)")


def stats(err: np.ndarray) -> tuple[float, float, float, int]:
    e = err[np.isfinite(err)]
    return float(np.median(e)), float(np.percentile(e, 80)), float(e.mean()), len(e)


def row(err: np.ndarray) -> str:
    med, p80, mean, n = stats(err)
    return f"{med:7.2f} {p80:7.2f} {mean:7.2f} {n:6d}"


def errors(matcher, db, scans: ScanSet) -> np.ndarray:
    res = matcher.fit(db).predict(scans)
    return np.linalg.norm(res.xy_m - scans.xy_m, axis=1)


def calibrated_walk(scans: ScanSet, db) -> tuple[ScanSet, float, float]:
    """Estimate (k, b) from the first CAL_SCANS scans (rows <= 3 s) and apply it to all."""
    dense = db.dense()
    first = np.argsort(scans.scans["t_ms"].to_numpy(), kind="stable")[:CAL_SCANS]
    rssi, age = align_scans(scans.subset(np.isin(np.arange(len(scans)), first)), dense.aps)
    rssi = np.where(age <= 3000, rssi, np.nan)
    cal = estimate_rssi_calibration(rssi, dense.mean_dbm, dense.var_db2)
    return scans.transformed(cal.k, cal.b), cal.k, cal.b


def floor_positions(obs: pd.DataFrame, folds: int, with_scans: bool
                    ) -> tuple[dict[str, list], list]:
    walks = np.unique(obs["trace_id"].to_numpy().astype(str))
    if folds and folds < len(walks):
        rng = np.random.default_rng(0)
        fold_of = dict(zip(rng.permutation(walks), np.arange(len(walks)) % folds))
        groups = [[w for w in walks if fold_of[w] == k] for k in range(folds)]
    else:
        groups = [[w] for w in walks]
    trace = obs["trace_id"].to_numpy().astype(str)
    out: dict[str, list] = {}
    cal_kb = []
    fresh = obs["age_ms"].to_numpy() <= 3000
    for held in groups:
        test = np.isin(trace, held)
        train, test_obs = obs[~test], obs[test]
        scans = scan_set(test_obs)
        scans3 = scan_set(obs[test & fresh])
        raw = build_fingerprints(train, cell_m=0, max_age_ms=None)
        raw3 = build_fingerprints(train, cell_m=0, max_age_ms=3000)
        grid = build_fingerprints(train)
        plain = WeightedKNN(5, weight_power=0, metric="euclidean", representation="dbm")
        out.setdefault("baseline", []).append(errors(plain, raw, scans))
        out.setdefault("baseline 3s", []).append(errors(plain, raw3, scans3))
        if with_scans:
            out.setdefault("scans+sorensen", []).append(
                errors(default_matcher(), build_fingerprints(train, cell_m=0), scans))
        knn = default_matcher().fit(grid)
        out.setdefault("default", []).append(errors(knn, grid, scans))
        out.setdefault("gaussian", []).append(errors(GaussianMatch(), grid, scans))
        for walk in held:  # device transforms, per walk
            one = scans.subset(scans.scans["trace_id"].to_numpy().astype(str) == walk)
            if len(one) == 0:
                continue
            for tk, tb in TRANSFORMS:
                moved = one.transformed(tk, tb)
                tag = f"k={tk:g},b={tb:g}"
                out.setdefault(f"{tag} untreated", []).append(errors(knn, grid, moved))
                fixed, k, b = calibrated_walk(moved, grid)
                cal_kb.append((tag, k * tk, k * tb + b))
                out.setdefault(f"{tag} calibrated", []).append(errors(knn, grid, fixed))
    return out, cal_kb


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", type=Path, default=Path("/tmp/indoormap-wifi-bench"))
    ap.add_argument("--folds", type=int, default=0, help="0 = leave one walk out")
    ap.add_argument("--floors", default="F1,F2,F3")
    ap.add_argument("--with-scans", action="store_true",
                    help="also indoormap's matcher over raw scans (no grid)")
    args = ap.parse_args()
    floors = args.floors.split(",")
    if not all((SITE / f / "path_data_files").is_dir() for f in floors):
        print(f"skipped: {SITE} not available")
        return 0
    prepare_store(args.store, floors)
    obs = {f: wifi_observations(processed_table(args.store, "wifi", floor=f)) for f in floors}
    split = "leave-one-walk-out" if args.folds == 0 else f"grouped {args.folds}-fold by walk"

    t = time.time()
    print(f"\nWi-Fi position error (m), {split}; truth = processed scan positions")
    print(f"{'floor':6} {'method':26} {'median':>7} {'p80':>7} {'mean':>7} {'scans':>6}")
    pooled: dict[str, list] = {}
    kb_all = []
    for f in floors:
        out, kb = floor_positions(obs[f], args.folds, args.with_scans)
        kb_all += kb
        for name, parts in out.items():
            e = np.concatenate(parts)
            pooled.setdefault(name, []).append(e)
            print(f"{f:6} {name:26} {row(e)}", flush=True)
    for name, parts in pooled.items():
        print(f"{'all':6} {name:26} {row(np.concatenate(parts))}")
    med = {n: stats(np.concatenate(p))[0] for n, p in pooled.items()}
    base = med["default"]
    print(f"\nDevice transforms on held-out walks (median over all floors; untransformed "
          f"{base:.2f} m); calibration from the first {CAL_SCANS} scans of each walk")
    kb = pd.DataFrame(kb_all, columns=["tag", "slope", "offset"])
    for tk, tb in TRANSFORMS:
        tag = f"k={tk:g},b={tb:g}"
        for kind in ("untreated", "calibrated"):
            name = f"{tag} {kind}"
            print(f"  {name:26} {med[name]:.2f} m  loss {100 * (med[name] / base - 1):+.1f} %")
        part = kb[kb["tag"] == tag]
        at70 = part["slope"] * -70 + part["offset"] + 70
        print(f"  {'':26} combined map after calibration: slope median "
              f"{part['slope'].median():.3f} (IQR {part['slope'].quantile(.75) - part['slope'].quantile(.25):.3f}), "
              f"error at -70 dBm median {at70.median():+.2f} dB (IQR "
              f"{at70.quantile(.75) - at70.quantile(.25):.2f}); ideal 1, 0")
    print(f"(positions and calibration: {time.time() - t:.0f} s)")

    t = time.time()
    cv = cross_validate_floor_model(obs, folds=10)
    print(f"\nFloor ({', '.join(floors)}), grouped {cv.folds}-fold by walk: per scan "
          f"{100 * cv.scan_accuracy:.2f} % of {cv.n_scans}, per {cv.window}-scan sequence "
          f"{100 * cv.sequence_accuracy:.2f} %, per walk {100 * cv.walk_accuracy:.2f} % of "
          f"{cv.n_walks} ({time.time() - t:.0f} s)")
    print(cv.confusion.to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
