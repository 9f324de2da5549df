"""Accuracy of the localizer and its baselines, 5-fold by walk.

1. Simulated site (``survey.sim`` preset ``default``: 3 floors of 80 x 50 m, 16 walks each;
   simulated once into ``--work``): truth at every step. Maps:

   - ``truth``: the simulator's field on a 0.25 m grid (a perfect map);
   - ``built``: ``mapping.build.build_floor`` from the survey walks of the other four folds
     (when the builder is importable).

2. Real traces ``../shared/ilc/site1`` F1-F3 (skipped when absent, or without the builder):
   maps built without the evaluated walks, errors at the recorded waypoints.

Every walk starts from its first Wi-Fi fix (``--radio bundle``, default: the fold bundle's
fingerprints, as ``indoormap localize``; truth maps have none and use ``--radio knn``, a kNN over
the other folds' scans; a walk without a fix starts at its first waypoint, the truth, and is
left out of the tables, which say how many were: a rule that takes a walk's every fix away
must not gain by it; ``--csv FILE`` writes every waypoint's error, those walks flagged), or with
``--radio ble`` as a phone that logs BLE only would run (an iPhone app): the Wi-Fi scans left
out, its first BLE fix and the fold bundle's BLE fingerprints over its 2 s BLE windows,
calibrated online as ``indoormap localize`` does (``--ble-rssi K,B``: their BLE RSSI read as
``k * rssi + b``, a phone on another scale; ``--ble-min-dbm X``: the weakest strongest beacon
a window needs to be located, :data:`localize.radio_match.BLE_MIN_STRONGEST_DBM` for this run);
except
``pdr@wp0``: PDR with 0.7 m steps from the first waypoint, the ILC baseline.
``name[smoothed]`` rows are the same filter smoothed offline over the whole walk
(:mod:`localize.smoothing`): not what a phone shows in real time. ``auto`` is what
``indoormap localize`` runs by default (the filter guided by the alignment, or the alignment
alone, by the fold bundle's measured map quality); ``indoormap`` runs the filter's default parameters;
``indoormap[paper]`` the papers' (W 3, K 70, T 0.05 on strength, azimuth and polar, radio for
the start only, 300 particles); ``indoormap[weinberg]`` the Weinberg step model. Prints, per data set, floor and method, the
error at the waypoints and (simulation) at every step: median, p80, mean (m).

Usage: ``python benchmarks/localize_accuracy.py [--work DIR] [--methods a,b] [--skip-real]
[--skip-sim] [--maps truth,built] [--radio bundle|knn|ble] [--ble-rssi K,B] [--ble-min-dbm X]
[--csv FILE]``
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from localize_eval import (
    ALL_METHODS,
    SHARED_SITE,
    RunResult,
    builder_available,
    built_bundle,
    fold_radio,
    folds_of,
    print_table,
    processed_store,
    real_walks,
    run_fold,
    sim_site,
    sim_walks,
    truth_bundle_of,
    with_ble_rssi,
)

from localize import radio_match
from localize.params import FilterParams


def run_floors(floors: dict, methods, params: FilterParams, label: str, steps: bool,
               radio: str = "bundle", rows: list[dict] | None = None) -> None:
    """floors: name -> (walks, folds, bundle_of(fold index)). Appends every waypoint's error
    to ``rows`` (data set, floor, method, trace id, whether the walk started at its first
    waypoint for want of a fix, waypoint index, error in m) when given."""
    pooled = RunResult()
    for floor, (walks, folds, bundle_of) in floors.items():
        t0 = time.time()
        res = RunResult()
        for i, test in enumerate(folds):
            bundle = bundle_of(i)
            res.merge(run_fold(walks, test, bundle, methods, params, start="wifi",
                               radio=None if radio == "ble" else
                               fold_radio(radio, walks, test, bundle), ble=radio == "ble"))
        print_table(f"{label} {floor}: {len(walks)} walks, 5-fold by walk "
                    f"({time.time() - t0:.0f} s)", res, methods,
                    ("wp", "step") if steps else ("wp",))
        pooled.merge(res)
        if rows is not None:
            rows.extend({"data": label.rstrip(","), "floor": floor, "method": m, "trace_id": t,
                         "fallback_start": t in res.fallback, "waypoint": i,
                         "error_m": float(err)}
                        for m in methods for t, errs in res.errors(m, fallback=True)
                        for i, err in enumerate(errs))
        for note in res.notes:
            print(f"  note: {note}")
    if len(floors) > 1:
        print_table(f"{label} all floors", pooled, methods, ("wp", "step") if steps else ("wp",))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description="localizer accuracy, 5-fold by walk")
    ap.add_argument("--work", type=Path, default=Path("benchmarks/.work"),
                    help="cache of the simulated site, stores, bundles and step summaries (their "
                         "names carry a hash of the code that made them)")
    ap.add_argument("--methods", default=",".join(ALL_METHODS))
    ap.add_argument("--maps", default="truth,built", help="simulation maps: truth, built")
    ap.add_argument("--params", default="{}", help="JSON FilterParams overrides")
    ap.add_argument("--radio", default="bundle", choices=("bundle", "knn", "ble"),
                    help="radio model: the bundle's Wi-Fi fingerprints (as indoormap localize; "
                         "truth maps have none and use the kNN), a kNN over training scans, "
                         "or the bundle's BLE fingerprints over the walks' BLE windows, their "
                         "Wi-Fi left out (a phone that logs BLE only, as an iPhone app)")
    ap.add_argument("--ble-rssi", default="1,0", metavar="K,B",
                    help="with --radio ble: the walks' BLE RSSI read as k * rssi + b (dBm), a "
                         "phone on another scale than the survey's (default 1,0: as recorded)")
    ap.add_argument("--ble-min-dbm", type=float, default=None, metavar="X",
                    help="with --radio ble: locate a BLE window only when its strongest known "
                         "beacon reads X dBm or more (default: "
                         "localize.radio_match.BLE_MIN_STRONGEST_DBM)")
    ap.add_argument("--csv", type=Path, default=None, metavar="FILE",
                    help="also write every waypoint's error (m) per data set, floor, method and "
                         "walk, the walks started at their first waypoint included and flagged")
    ap.add_argument("--skip-sim", action="store_true")
    ap.add_argument("--skip-real", action="store_true")
    args = ap.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    ble_k, ble_b = (float(v) for v in args.ble_rssi.split(","))
    if (ble_k, ble_b) != (1.0, 0.0):
        if args.radio != "ble":
            ap.error("--ble-rssi needs --radio ble")
        print(f"BLE RSSI read as {ble_k:g} * rssi {ble_b:+g} dB")
    if args.ble_min_dbm is not None:
        if args.radio != "ble":
            ap.error("--ble-min-dbm needs --radio ble")
        # The module constant is what radio_match.min_strongest_dbm("ble") returns to the
        # positioner and the mapping matcher alike; set for this process only.
        radio_match.BLE_MIN_STRONGEST_DBM = args.ble_min_dbm
    if args.radio == "ble":
        print(f"BLE windows located when their strongest beacon reads >= "
              f"{radio_match.min_strongest_dbm('ble'):g} dBm")
    d = json.loads(FilterParams().to_json())
    d.update(json.loads(args.params))
    params = FilterParams.from_dict(d)
    print(f"parameters: {params.to_json()}")

    rows: list[dict] | None = [] if args.csv else None
    run_all(args, methods, params, ble_k, ble_b, rows)
    if rows is not None:
        write_csv(rows, args.csv)


def write_csv(rows: list[dict], path: Path) -> None:
    """The waypoint errors, written to a temporary sibling and moved into place."""
    import pandas as pd

    tmp = path.with_name(f".{path.name}.tmp")
    pd.DataFrame(rows, columns=["data", "floor", "method", "trace_id", "fallback_start",
                                "waypoint", "error_m"]).to_csv(tmp, index=False)
    tmp.replace(path)
    print(f"\nwaypoint errors: {path} ({len(rows)} rows)")


def run_all(args, methods, params: FilterParams, ble_k: float, ble_b: float,
            rows: list[dict] | None) -> None:
    """The simulated and the real parts, as ``args`` selects."""
    if not args.skip_sim:
        site = sim_site(args.work)
        names = ("F1", "F2", "F3")
        data = {f: with_ble_rssi(sim_walks(site, f, args.work), ble_k, ble_b) for f in names}
        kinds = [k.strip() for k in args.maps.split(",")]
        if "truth" in kinds:
            floors = {}
            for f in names:
                b = truth_bundle_of(site, f, args.work)
                floors[f] = (data[f], folds_of(data[f]), lambda i, b=b: b)
            run_floors(floors, methods, params, "SIMULATED site, truth maps,", steps=True,
                       radio=args.radio, rows=rows)
        if "built" in kinds:
            if not builder_available():
                print("\nSIMULATED site, built maps: skipped (mapping.build not available)")
            else:
                store = processed_store(site.name, [site / f for f in names], args.work)
                floors = {}
                for f in names:
                    folds = folds_of(data[f])
                    floors[f] = (data[f], folds,
                                 lambda i, f=f, folds=folds: built_bundle(
                                     store, site / f, set(folds[i]), args.work, site.name))
                run_floors(floors, methods, params,
                           "SIMULATED site, maps built without the test walks,", steps=True,
                           radio=args.radio, rows=rows)

    if args.skip_real:
        return
    if not SHARED_SITE.is_dir():
        print(f"\nREAL traces: skipped ({SHARED_SITE} is absent)")
        return
    if not builder_available():
        print("\nREAL traces: skipped (mapping.build, the map builder, is not available)")
        return
    floor_dirs = [SHARED_SITE / f for f in ("F1", "F2", "F3")]
    store = processed_store("ilc_site1", floor_dirs, args.work)
    floors = {}
    for fd in floor_dirs:
        walks = with_ble_rssi(real_walks(fd, args.work), ble_k, ble_b)
        folds = folds_of(walks)
        floors[fd.name] = (walks, folds, lambda i, fd=fd, folds=folds: built_bundle(
            store, fd, set(folds[i]), args.work, "ilc"))
    run_floors(floors, methods, params, "REAL traces site1, maps built without the test walks,",
               steps=False, radio=args.radio, rows=rows)


if __name__ == "__main__":
    main()
