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
- ``default``: what ``indoormap build`` ships, rebuilt per fold from the training walks only
  (:func:`mapping.radio_build.site_radio`: device table, AP selection over the three floors,
  1 m reference points, Wi-Fi rows up to 6 s) matched as the localizer does (Sorensen kNN on
  powed RSSI, reference distances mixed with their 1 m neighbourhood's, k = 5, 1/d^4; query
  rows older than 2.5 s down-weighted), every scan on its own;
- ``default, whole walk``: the same distances, every held-out walk's scans matched together
  (:func:`mapping.matching.default_walk_matcher`, forward-backward over the reference points:
  what ``indoormap wifi-locate`` reports for a recorded walk);
- ``gaussian``: the probabilistic match on the same reference points;
- ``ble`` (and ``ble, whole walk``): the shipped BLE fingerprints on held-out BLE windows
  (2 s), scored separately (BLE windows are not Wi-Fi scans; the count differs).

Floors: the shipped floor model (logistic regression on transmitter levels, fitted per fold on
the training walks of all floors): accuracy per scan, per 5-scan sequence and per walk. The
same for the site bundle's BLE floor model (the fallback for walks without Wi-Fi that name no
floor), on the held-out BLE windows (2 s); its walk figure is the rule the localizer uses
(:meth:`localize.floors.SiteMaps.choose`: summed log-probabilities of the walk's windows). The
folds group the Wi-Fi walks: a walk with BLE and no Wi-Fi is never held out. Both models
again on held-out RSSI mapped through the transforms below (phones the device table does not
know), and through ``rssi - 12`` with the rows that then read below -100 dBm lost (a phone
that hears less, not only reads lower): the Wi-Fi model (levels) as it reads and calibrated
online against the fingerprints of the floor the raw scans chose (the first 8 scans, what
``localize`` does); the BLE model (presence) as it reads, which is what ``localize`` does.

Device calibration: every held-out walk's RSSI is mapped through ``0.85 * rssi - 8`` and,
harsher, ``rssi - 12`` (phones that report weaker values). Without calibration the walk is
matched as is; with calibration, ``localize.rssi_calibration`` estimates ``(k, b)`` from the
walk's first 8 scans (rows <= 3 s) and the whole walk is calibrated. Reported: median error
and its loss against the untransformed walks (target < 10 %), and how close the combined map
(transform then calibration) comes to the identity.

Runtime on 2 cores: ``--folds 10`` about 4 min; leave-one-walk-out (305 folds, the floor
model then measured by 10-fold) about 60 min.
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
from mapping.matching import GaussianMatch, WeightedKNN, align_scans, default_matcher
from mapping.radio_build import RadioParams, site_observations
from mapping.radio_scans import ScanSet, scan_set
from mapping.radio_validation import heldout_radio, walk_folds
from survey.ingest import ingest
from survey.process_store import process_store
from survey.store import SurveyStore

from real_data import ILC_SITE1  # $INDOORMAP_ILC or ../shared/ilc

SITE = ILC_SITE1
TRANSFORMS = ((0.85, -8.0), (1.0, -12.0))
CAL_SCANS = 8
#: the floor models' phones (k, b, rows below this many dBm lost or None): the survey phones'
#: own RSSI too (calibrated online as well), and a phone that hears less
FLOOR_PHONES = ((1.0, 0.0, None),) + tuple((k, b, None) for k, b in TRANSFORMS) + \
    ((1.0, -12.0, -100.0),)


def phone_tag(k: float, b: float, lost_below: float | None) -> str:
    return f"k={k:g},b={b:g}" + ("" if lost_below is None else f",lost<{lost_below:g}")


def as_phone(scans: ScanSet, k: float, b: float, lost_below: float | None) -> ScanSet:
    """``scans`` as a phone would read them whose RSSI is ``k * rssi + b`` (dBm) and which
    hears nothing below ``lost_below`` dBm (None: hears all)."""
    moved = scans.transformed(k, b)
    if lost_below is None:
        return moved
    rssi = np.where(moved.rssi_dbm < lost_below, np.nan, moved.rssi_dbm)
    return ScanSet(moved.scans, moved.aps, rssi, moved.age_ms)


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
    """Estimate (k, b) from the first ``CAL_SCANS`` scans (rows <= 3 s) and apply it to all."""
    dense = db.dense()
    first = np.argsort(scans.scans["t_ms"].to_numpy(), kind="stable")[:CAL_SCANS]
    rssi, age = align_scans(scans.subset(np.isin(np.arange(len(scans)), first)), dense.aps)
    rssi = np.where(age > 3000, np.nan, rssi)
    cal = estimate_rssi_calibration(rssi, dense.mean_dbm, dense.var_db2)
    return scans.transformed(cal.k, cal.b), cal.k, cal.b


def evaluate(obs: dict[str, pd.DataFrame], device_of: pd.Series, floors: list[str],
             folds: int, with_scans: bool, with_floors: bool
             ) -> tuple[dict[tuple[str, str], list], list, dict]:
    """Errors per (floor, method), calibration results, floor predictions."""
    wifi = obs["wifi"]
    out: dict[tuple[str, str], list] = {}
    cal_kb: list = []
    floor_rows: dict[str, list] = {k: [] for k in ("truth", "scan", "seq", "walk_truth",
                                                   "walk")}
    floor_rows["ble"] = {k: [] for k in floor_rows}
    w_trace = wifi["trace_id"].to_numpy().astype(str)
    groups = walk_folds(w_trace, folds)
    t0 = time.time()
    done = [0]

    def on_fold(held, radio, test_obs) -> None:
        """The baselines and the extra measurements of one fold (``default`` and ``ble`` come
        from :func:`mapping.radio_validation.heldout_radio`)."""
        w_test = np.isin(w_trace, held)
        test_cal = test_obs["wifi"]
        for f in floors:
            on_f = wifi["floor"].to_numpy() == f
            train_raw, raw_test = wifi[~w_test & on_f], wifi[w_test & on_f]
            test_f = test_cal[test_cal["floor"].to_numpy() == f]
            if len(test_f) == 0:
                continue
            scans = scan_set(test_f)
            plain = WeightedKNN(5, weight_power=0, metric="euclidean", representation="dbm")
            out.setdefault((f, "baseline"), []).append(
                errors(plain, build_fingerprints(train_raw, cell_m=0, max_age_ms=None),
                       scan_set(raw_test)))
            out.setdefault((f, "baseline 3s"), []).append(
                errors(plain, build_fingerprints(train_raw, cell_m=0, max_age_ms=3000),
                       scan_set(raw_test[raw_test["age_ms"] <= 3000])))
            if with_scans:
                out.setdefault((f, "scans+sorensen"), []).append(
                    errors(default_matcher(), build_fingerprints(train_raw, cell_m=0), scans))
            grid = radio.fingerprints[(f, "wifi")]
            knn = default_matcher().fit(grid)
            out.setdefault((f, "gaussian"), []).append(errors(GaussianMatch(), grid, scans))
            for walk in held:  # device transforms, per walk
                one = scans.subset(scans.scans["trace_id"].to_numpy().astype(str) == walk)
                if len(one) == 0:
                    continue
                for tk, tb in ((1.0, 0.0),) + TRANSFORMS:
                    moved = one.transformed(tk, tb)
                    tag = f"k={tk:g},b={tb:g}"
                    out.setdefault((f, f"{tag} untreated"), []).append(errors(knn, grid, moved))
                    fixed, k, b = calibrated_walk(moved, grid)
                    cal_kb.append((tag, k * tk, k * tb + b))
                    out.setdefault((f, f"{tag} calibrated"), []).append(
                        errors(knn, grid, fixed))
        for model, test, rows in ((radio.floor_model, test_cal, floor_rows),
                                  (radio.ble_floor_model, test_obs.get("ble"),
                                   floor_rows["ble"])):
            if model is None or test is None or not len(test):
                continue
            s = scan_set(test)
            rows["truth"].append(test.groupby("scan_id", sort=True)["floor"].first()
                                 .to_numpy())
            rows["scan"].append(model.predict(s))
            rows["seq"].append(model.predict_sequence(s, 5))
            w = model.predict_walks(s)
            rows["walk"].append(w.to_numpy())
            rows["walk_truth"].append(test.groupby("trace_id")["floor"].first()
                                      .reindex(w.index).to_numpy())
            for phone in FLOOR_PHONES:
                moved = as_phone(s, *phone)  # a phone the device table does not know
                first = model.predict_walks(moved)
                tag = phone_tag(*phone)
                rows.setdefault(f"scan {tag}", []).append(model.predict(moved))
                rows.setdefault(f"walk {tag}", []).append(first.reindex(w.index).to_numpy())
                if model is not radio.floor_model:  # BLE: read as it is
                    continue
                # as the localizer does (SiteMaps.choose): calibrated online against the
                # fingerprints of the floor the raw scans chose, then classified again
                walk_of = moved.scans["trace_id"].to_numpy().astype(str)
                scan_fix = np.full(len(moved), "", dtype=object)
                walk_fix = {}
                for walk, f0 in first.items():
                    mine = walk_of == walk
                    if f0 == "" or (f0, "wifi") not in radio.fingerprints:
                        continue
                    fixed, _, _ = calibrated_walk(moved.subset(mine),
                                                  radio.fingerprints[(f0, "wifi")])
                    scan_fix[mine] = model.predict(fixed)
                    walk_fix[walk] = model.predict_walks(fixed).iloc[0]
                rows.setdefault(f"scan {tag} cal", []).append(scan_fix.astype(str))
                rows.setdefault(f"walk {tag} cal", []).append(
                    pd.Series(walk_fix, dtype=object).reindex(w.index).to_numpy())
        done[0] += 1
        if done[0] % max(1, len(groups) // 10) == 0:
            print(f"  fold {done[0]}/{len(groups)} ({time.time() - t0:.0f} s)", file=sys.stderr,
                  flush=True)

    params = RadioParams(floor_model=with_floors, floor_cv_folds=0)
    shipped = heldout_radio(obs, device_of, floors, groups, params=params, on_fold=on_fold)
    for (f, kind), err in shipped.items():
        out[(f, SHIPPED_NAME.get(kind, kind))] = [err]
    return dict(sorted(out.items(), key=lambda kv: (kv[0][0], METHOD_ORDER.get(kv[0][1], 9)))), \
        cal_kb, floor_rows


SHIPPED_NAME = {"wifi": "default", "wifi walk": "default, whole walk",
                "ble walk": "ble, whole walk"}
METHOD_ORDER = {"baseline": 0, "baseline 3s": 1, "scans+sorensen": 2, "default": 3,
                "default, whole walk": 4, "gaussian": 5, "ble": 6, "ble, whole walk": 7}


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
    store = SurveyStore.open(args.store)
    obs = {k: site_observations(store, None, floors, k) for k in ("wifi", "ble")}
    device_of = store.catalog().set_index("trace_id")["device_model"].astype(str)
    split = "leave-one-walk-out" if args.folds == 0 else f"grouped {args.folds}-fold by walk"

    t = time.time()
    out, kb_all, fl = evaluate(obs, device_of, floors, args.folds, args.with_scans,
                               with_floors=args.folds != 0)
    print(f"\nWi-Fi position error (m), {split}; truth = processed scan positions")
    print(f"{'floor':6} {'method':26} {'median':>7} {'p80':>7} {'mean':>7} {'scans':>6}")
    pooled: dict[str, list] = {}
    for (f, name), parts in out.items():
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
        iqr = part["slope"].quantile(.75) - part["slope"].quantile(.25)
        print(f"  {'':26} combined map after calibration: slope median "
              f"{part['slope'].median():.3f} (IQR {iqr:.3f}), error at -70 dBm median "
              f"{at70.median():+.2f} dB (IQR {at70.quantile(.75) - at70.quantile(.25):.2f}); "
              "ideal 1, 0")
    print(f"(positions and calibration: {time.time() - t:.0f} s)")

    if not fl["truth"]:  # leave-one-walk-out: the floor model by 10-fold
        t = time.time()
        _, _, fl = evaluate(obs, device_of, floors, 10, False, with_floors=True)
        print(f"(floor model by grouped 10-fold: {time.time() - t:.0f} s)")
    for rows, what, scans in ((fl, "shipped floor model", "scan"),
                              (fl["ble"], "BLE floor model (fallback without Wi-Fi)",
                               "BLE window")):
        if not rows["truth"]:
            print(f"\nFloor: no {what}")
            continue
        truth, scan, seq = (np.concatenate(rows[k]) for k in ("truth", "scan", "seq"))
        walk, walk_truth = np.concatenate(rows["walk"]), np.concatenate(rows["walk_truth"])
        print(f"\nFloor ({', '.join(floors)}), {what}, walks held out: per {scans} "
              f"{100 * (scan == truth).mean():.2f} % of {len(truth)}, per 5-{scans} sequence "
              f"{100 * (seq == truth).mean():.2f} %, per walk "
              f"{100 * (walk == walk_truth).mean():.2f} % of {len(walk)}")
        print(pd.crosstab(pd.Series(truth, name="floor"), pd.Series(scan, name="pred"))
              .to_string())
        for phone in FLOOR_PHONES:
            tag = phone_tag(*phone)
            cal_what = ("calibrated online on the floor the raw scans chose, first "
                        f"{CAL_SCANS} scans, as localize does")
            for cal, what in (("", "as it reads"),) + (((" cal", cal_what),) if rows is fl
                                                         else ()):
                moved, moved_walk = (np.concatenate(rows[f"{k} {tag}{cal}"])
                                     for k in ("scan", "walk"))
                print(f"  RSSI mapped through {tag} ({what}): per {scans} "
                      f"{100 * (moved == truth).mean():.2f} %, per walk "
                      f"{100 * (moved_walk == walk_truth).mean():.2f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
