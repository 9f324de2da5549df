"""Grid search of the mass-centered update's W, K, T (and related options), cross-validated.

Every configuration localizes every walk of every floor with maps that do not contain the
walk (5-fold by walk; on the simulated site the truth map is walk-free anyway). A
configuration is then chosen *per floor* by its waypoint error on the *other* floors
(leave-one-floor-out), so the error reported for a floor never selected its own parameters.

Usage::

    python benchmarks/localize_tune.py sim  [--work DIR] [--grid small|wkt|full]
    python benchmarks/localize_tune.py real [--work DIR] [--grid wkt|radio] [--max-walks 40]

Prints one line per configuration (errors per floor and pooled) and the leave-one-floor-out
selection. Results are also appended as JSON lines to ``WORK/tune_<source>.jsonl``.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import sys
import time
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
    radio_for,
    real_walks,
    run_fold,
    sim_site,
    sim_walks,
    truth_bundle_of,
)

from localize.params import FilterParams


def grid(kind: str) -> list[dict]:
    """Configurations as FilterParams overrides (``with_features`` style for features).

    ``small``: W x T x polar on/off. ``wkt``: W x span x T on strength alone, then the
    experiments: K (which cancels when weights are normalised every step), smoothed
    observations, the map's uncertainty raster, azimuth + polar on UFH steps, and the
    compass-deviation feature. ``radio``: the start and the Wi-Fi side (start square, radio
    likelihood width, outlier share, injection rule; ``positioner`` entries change the
    fingerprint positioner)."""
    out = []
    if kind == "radio":
        out += [{}, {"init_from_fix_scale": 3.0}, {"init_half_width_m": 5.0},
                {"positioner": {"likelihood_sigma_m": 5.0}},
                {"positioner": {"likelihood_sigma_m": 8.0}},
                {"radio_outlier": 0.03}, {"radio_outlier": 0.3},
                {"radio_inject_distance_m": 0.0}, {"radio_inject_fraction": 0.0},
                {"radio_inject_rule": "fit"},
                {"radio_inject_rule": "fit", "radio_inject_fraction": 0.3},
                {"radio_inject_rule": "fit", "init_half_width_m": 5.0},
                {"init_half_width_m": 8.0, "radio_inject_fraction": 0.0}]
        return out
    if kind == "wkt":
        off = {"polar": {"enabled": False}, "azimuth": {"enabled": False}}
        for w, span, t in itertools.product((1, 3, 8), (1, 8), (0.05, 0.5, 2.0)):
            out.append({"strength": {"window": w, "span": span, "threshold": t}, **off})
        base = {"window": 3, "span": 1, "threshold": 0.5}
        out += [
            {"strength": {**base, "award": 1.0}, **off},
            {"strength": {**base, "smooth": 3}, **off},
            {"strength": {**base, "smooth": 3, "span": 3}, **off},
            {"strength": {**base, "std_scale": 1.0}, **off},
            {"strength": {**base, "std_scale": 0.3}, **off},
            {"strength": base, "polar": {"enabled": True, "threshold": 0.5},
             "azimuth": {"enabled": True, "threshold": 1.0}},
            {"strength": base, **off, "deviation": {"enabled": True, "threshold": 1.0}},
            {"strength": {"enabled": False}, **off},
        ]
        return out
    if kind == "small":
        for w, t, pol in itertools.product((1, 3, 6), (0.05, 0.3, 1.0), (False, True)):
            out.append({"strength": {"window": w, "threshold": t},
                        "polar": {"enabled": pol, "window": w},
                        "azimuth": {"enabled": False}})
        return out
    for w, k, t in itertools.product((1, 2, 3, 5, 8), (1.0, 70.0), (0.05, 0.2, 0.5, 1.0, 2.0)):
        out.append({"strength": {"window": w, "award": k, "threshold": t},
                    "polar": {"enabled": False}, "azimuth": {"enabled": False}})
    return out


def params_of(base: FilterParams, over: dict) -> FilterParams:
    feats = {k: v for k, v in over.items()
             if k in ("strength", "azimuth", "polar", "deviation")}
    rest = {k: v for k, v in over.items() if k not in feats and k != "positioner"}
    p = base.with_features(**feats)
    if rest:
        d = json.loads(p.to_json())
        d.update(rest)
        p = FilterParams.from_dict(d)
    return p


def prepare(source: str, work: Path):
    """floor -> (walks, folds, [(bundle, radio) per fold])."""
    data = {}
    if source == "sim":
        site = sim_site(work)
        for floor in ("F1", "F2", "F3"):
            walks = sim_walks(site, floor, work)
            folds = folds_of(walks)
            b = truth_bundle_of(site, floor, work)
            data[floor] = (walks, folds, [(b, radio_for(walks, set(f))) for f in folds])
        return data
    if not SHARED_SITE.is_dir() or not builder_available():
        raise SystemExit("real data needs ../shared/ilc/site1 and mapping.build")
    floors = [SHARED_SITE / f for f in ("F1", "F2", "F3")]
    store = processed_store("ilc_site1", floors, work)
    for fd in floors:
        walks = real_walks(fd, work)
        folds = folds_of(walks)
        bundles = [built_bundle(store, fd, set(f), work, "ilc") for f in folds]
        data[fd.name] = (walks, folds, [(b, fold_radio("bundle", walks, f, b))
                                        for f, b in zip(folds, bundles)])
    return data


def evaluate(data, params: FilterParams, start: str, max_walks: int = 0,
             positioner: dict | None = None, seeds: int = 1) -> dict[str, RunResult]:
    """Errors of ``params`` per floor, pooled over ``seeds`` runs (seeds 0, 1, ...)."""
    out = {}
    for floor, (walks, folds, maps) in data.items():
        res = RunResult()
        for test, (bundle, radio) in zip(folds, maps):
            if positioner and radio is not None:
                radio = dataclasses.replace(radio, **positioner)
            if max_walks:
                test = test[:max(1, max_walks // len(folds))]
            for seed in range(seeds):
                res.merge(run_fold(walks, test, bundle, ["indoormap"], params, start=start,
                                   radio=radio, seed=seed))
        out[floor] = res
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description="cross-validated grid search of W, K, T")
    ap.add_argument("source", choices=["sim", "real"])
    ap.add_argument("--work", type=Path, default=Path("benchmarks/.work"))
    ap.add_argument("--grid", choices=["small", "wkt", "full", "radio"], default="wkt")
    ap.add_argument("--max-walks", type=int, default=0,
                    help="evaluate at most this many walks per floor (0 = all)")
    ap.add_argument("--start", choices=["wifi", "waypoint", "truth"], default="wifi")
    ap.add_argument("--base", default="{}", help="JSON overrides applied to every config")
    ap.add_argument("--configs", default=None,
                    help="JSON list of configurations to run instead of --grid")
    ap.add_argument("--seeds", type=int, default=1,
                    help="runs per configuration (filter seeds 0..N-1), errors pooled: the "
                         "filter is chaotic, one seed moves a median by 0.1-0.3 m")
    args = ap.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    data = prepare(args.source, args.work)
    base = params_of(FilterParams(), json.loads(args.base))
    configs = json.loads(args.configs) if args.configs else grid(args.grid)
    rows = []
    log = args.work / f"tune_{args.source}.jsonl"
    for i, over in enumerate(configs):
        t0 = time.time()
        res = evaluate(data, params_of(base, over), args.start, args.max_walks,
                       over.get("positioner"), args.seeds)
        per = {f: r.summary("indoormap") for f, r in res.items()}
        pooled = RunResult()
        for r in res.values():
            pooled.merge(r)
        per["all"] = pooled.summary("indoormap")
        rows.append((over, per))
        with open(log, "a") as fh:
            fh.write(json.dumps({"base": json.loads(args.base), "start": args.start,
                                 "max_walks": args.max_walks, "seeds": args.seeds, "config": over,
                                 "result": per}) + "\n")
        print(f"[{i + 1}/{len(configs)} {time.time() - t0:.0f}s] {json.dumps(over)}")
        print("    " + "  ".join(f"{f}: {s['median']:.2f}/{s['p80']:.2f}/{s['mean']:.2f}"
                                 for f, s in per.items()) + "  (median/p80/mean m)",
              flush=True)
    floors = list(data)
    print("\nLeave-one-floor-out selection (criterion: mean of median and p80 at waypoints "
          "on the other floors)")
    for f in floors:
        others = [g for g in floors if g != f]

        def score(row, others=others):
            return float(np.mean([0.5 * (row[1][g]["median"] + row[1][g]["p80"])
                                  for g in others]))

        best = min(rows, key=score)
        s = best[1][f]
        print(f"  {f}: chosen {json.dumps(best[0])} -> {f} median {s['median']:.2f} "
              f"p80 {s['p80']:.2f} mean {s['mean']:.2f} m")


if __name__ == "__main__":
    main()
