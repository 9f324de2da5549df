"""How far Wi-Fi fixes can take a localizer that starts from them (issue #7's real-trace limit).

On ``../shared/ilc/site1`` F1-F3 (skips cleanly without it), with the same walks, 5 folds by
walk and fold bundles as ``benchmarks/localize_accuracy.py`` (maps and fingerprints built
without the evaluated walks), every held-out scan is located by the fold bundle's
fingerprints (``FingerprintPositioner.locate``, what the filter starts from) and compared with
the walk's position at the scan time (interpolated between waypoints). Prints:

1. **Fix errors along a walk**: median / p80 of one fix, and the correlation of the error
   vectors (x and y averaged) between a fix and the fix ``k`` scans later, with the median time
   between them. Independent errors would give 0.
2. **A perfect track placed by its fixes**: a track of the right shape (the truth itself)
   shifted by the mean error of the walk's first ``k`` fixes: the error a flawless
   step-and-heading track keeps when its only absolute reference is the plain mean of those
   fixes, next to the same walks placed by all their fixes (offline). It is the error of one
   estimator, not a lower bound for every method (walls and the magnetic map add
   information); correlated errors do not average out, so it stays well above independent
   fixes' ``sigma / sqrt(k)``. One value per walk (the filter rows count every waypoint).
3. **The filter, same folds** (unless ``--no-filter``): indoormap's defaults from the first
   Wi-Fi fix and from the first waypoint (a right start), errors at waypoints.

Usage: ``python benchmarks/localize_bound.py [--work DIR] [--no-filter]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from localize_eval import (
    SHARED_SITE,
    RunResult,
    builder_available,
    built_bundle,
    fold_radio,
    folds_of,
    processed_store,
    real_walks,
    run_fold,
)

from localize.evaluate import summarize
from localize.params import FilterParams

LAGS = (1, 2, 3, 5, 8)
FIRST_K = (1, 2, 3, 5, 8, 13)


def fix_errors(walks, test: list[str], radio) -> list[np.ndarray]:
    """Per walk of ``test``: rows ``(ex, ey, t_s)`` of its scans ``radio`` locates (m, m,
    s); scans outside the walk's waypoints are left out (no reference there)."""
    out = []
    for w in walks:
        if w.trace_id not in test:
            continue
        rows = [(fix[0] - xy[0], fix[1] - xy[1], scan.t_ms / 1000.0)
                for scan, xy in w.radio_refs if (fix := radio.locate(scan)) is not None]
        if rows:
            out.append(np.array(rows))
    return out


def lag_correlation(errs: list[np.ndarray], lag: int) -> tuple[float, float]:
    """(correlation of fix errors ``lag`` scans apart, x and y averaged; median time apart
    (s))."""
    pairs = [np.c_[e[:-lag], e[lag:]] for e in errs if len(e) > lag]
    if not pairs:
        return float("nan"), float("nan")
    p = np.concatenate(pairs)
    r = 0.5 * (np.corrcoef(p[:, 0], p[:, 3])[0, 1] + np.corrcoef(p[:, 1], p[:, 4])[0, 1])
    return float(r), float(np.median(p[:, 5] - p[:, 2]))


def translation_error(errs: list[np.ndarray], k: int | None) -> np.ndarray:
    """Per walk with at least ``k`` fixes: length of the mean error vector of its first ``k``
    (all when None) fixes (m)."""
    return np.array([np.hypot(*e[:k, :2].mean(axis=0)) for e in errs
                     if k is None or len(e) >= k])


def stats(v: np.ndarray) -> str:
    s = summarize(v)
    return "   -      -   " if s["n"] == 0 else f"{s['median']:5.2f} {s['p80']:6.2f}"


def report(label: str, errs: list[np.ndarray]) -> None:
    if not errs:
        print(f"\n{label}: no located scan")
        return
    single = np.concatenate([np.hypot(e[:, 0], e[:, 1]) for e in errs])
    print(f"\n{label}: {len(errs)} walks, {len(single)} fixes; one fix {stats(single)} m "
          "(median, p80)")
    print("  fix error correlation, k scans apart:  " + "  ".join(
        f"k={k}: {r:.2f} ({dt:.1f} s)" for k in LAGS
        for r, dt in [lag_correlation(errs, k)]))
    print("  perfect-shape track shifted by the mean error of its first k fixes, and of all "
          "its fixes on the same walks (median, p80 m; walks):")
    for k in (*FIRST_K, None):
        v = translation_error(errs, k)
        same = translation_error([e for e in errs if k is None or len(e) >= k], None)
        print(f"    {'all' if k is None else k:>4}  {stats(v)}   all: {stats(same)}  "
              f"({len(v)})")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, default=Path("benchmarks/.work"),
                    help="cache shared with localize_accuracy.py")
    ap.add_argument("--no-filter", action="store_true", help="skip the filter runs")
    args = ap.parse_args(argv)
    if not SHARED_SITE.is_dir():
        print(f"skipped: {SHARED_SITE} is absent")
        return 0
    if not builder_available():
        print("skipped: mapping.build, the map builder, is not available")
        return 0
    args.work.mkdir(parents=True, exist_ok=True)
    floor_dirs = [SHARED_SITE / f for f in ("F1", "F2", "F3")]
    store = processed_store("ilc_site1", floor_dirs, args.work)
    pooled, runs = [], {"wifi": RunResult(), "waypoint": RunResult()}
    for fd in floor_dirs:
        walks = real_walks(fd, args.work)
        errs = []
        for test in folds_of(walks):
            b = built_bundle(store, fd, set(test), args.work, "ilc")
            radio = fold_radio("bundle", walks, test, b)  # as localize_accuracy.py
            errs.extend(fix_errors(walks, test, radio))
            if not args.no_filter:
                for start, res in runs.items():
                    res.merge(run_fold(walks, test, b, ["indoormap"], FilterParams(),
                                       start=start, radio=radio))
        report(f"site1 {fd.name}", errs)
        pooled.extend(errs)
    report("site1 F1-F3", pooled)
    if not args.no_filter:
        print("\nindoormap (defaults), errors at waypoints, F1-F3, 5-fold by walk:")
        for start, res in runs.items():
            s = res.summary("indoormap")
            name = "from the Wi-Fi fix" if start == "wifi" else "from the first waypoint"
            print(f"  {name:<24} median {s['median']:.2f}  p80 {s['p80']:.2f}  "
                  f"mean {s['mean']:.2f} m")
        for note in runs["wifi"].notes:
            print(f"  note: {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
