"""What ``indoormap bundle info`` and ``bundle diff`` say about bundles, as plain text lines.

Pure functions of loaded :class:`~localize.bundle.MapBundle` objects (no printing), so that a
notebook gets the same report as the command line.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from localize.bundle import is_json_number
from localize.methods import auto_method

if TYPE_CHECKING:
    from localize.bundle import Grid, MapBundle


def metric_lines(manifest: dict) -> dict[str, str]:
    """What a bundle's build chose and reached, a line each (keyed ``smoothing``,
    ``heldout``, ``coverage``, ``floor_model``, ``ble_floor_model``): a floor bundle's
    smoothing picked by cross-validation, its strength map's held-out scores (and the method
    ``localize --method auto`` takes there) and the survey's coverage of the reachable area; a
    site bundle's floor models with their cross-validated accuracy."""
    mt = manifest.get("metrics") or {}
    lines = {}
    if isinstance(mt.get("interpolator"), str):
        scores = mt.get("smoothing_cv_shape_rmse_ut")
        numbers = [v for v in scores.values() if is_json_number(v)] \
            if isinstance(scores, dict) else []
        best = min(numbers) if numbers else None
        parts = [mt["interpolator"]] + [
            f"{label} {mt[key]:g}{unit}" for key, label, unit in (
                ("bandwidth_m", "bandwidth", " m"), ("prior_walks", "shrinkage", " walks"),
                ("slope_ridge", "slope ridge", ""), ("curvature_ridge", "curvature ridge", ""))
            if is_json_number(mt.get(key))]
        lines["smoothing"] = ("smoothing " + ", ".join(parts)
                              + (f" (cross-validated shape RMSE {best:.2f} uT)" if best else ""))
    held = mt.get("heldout_strength")
    if isinstance(held, dict) and is_json_number(held.get("skill")):
        corr = [f"{span} {held[k]:.2f}" for k, span in (("corr_0.7m", "0.7 m"),
                                                         ("corr_5m", "5 m"))
                if is_json_number(held.get(k))]
        lines["heldout"] = (f"strength on walks the map did not see ({held.get('folds', '?')} "
                            f"folds of {held.get('n_walks', '?')} walks): skill "
                            f"{held['skill']:.2f}"
                            + (f", change correlation over {', '.join(corr)}" if corr else "")
                            + f"; localize --method auto runs {auto_method(mt).label}")
    cov = mt.get("coverage")
    if isinstance(cov, dict) and cov:
        lines["coverage"] = "reachable area near a sample: " + ", ".join(
            f"{100 * v:.0f} % within {k.removeprefix('within_').removesuffix('m')} m"
            for k, v in cov.items() if is_json_number(v))
    for key in ("floor_model", "ble_floor_model"):
        fm = mt.get(key)
        if isinstance(fm, dict) and isinstance(fm.get("floors"), list):
            kind = "Wi-Fi" if fm.get("kind") == "wifi" else "BLE" if fm.get("kind") == "ble" \
                else str(fm.get("kind", "?"))
            unit = "scan" if kind == "Wi-Fi" else "window"
            cv = [f"{100 * fm[k]:.1f} % per {what}" for k, what in (
                ("cv_scan_accuracy", unit), ("cv_walk_accuracy", "walk"))
                if is_json_number(fm.get(k))]
            lines[key] = (f"floor model ({kind}, {fm.get('transmitters', '?')} transmitters): "
                          f"floors {', '.join(map(str, fm['floors']))}"
                          + (f"; cross-validated {', '.join(cv)}" if cv else ""))
    return lines


def plan_text(manifest: dict) -> str:
    """The floor plan a floor bundle was built on, as ``file (sha256 prefix)`` per file read
    (``geojson_map.json (3f2a9c01b7e4), floor_info.json (...)``); ``not recorded`` for a
    bundle built before plans were recorded or on a plan made in code."""
    files = manifest.get("build", {}).get("floor_plan")
    if not isinstance(files, list) or not files:
        return "not recorded"
    return ", ".join(f"{f.get('file')} ({str(f.get('sha256'))[:12]})" for f in files
                     if isinstance(f, dict))


def _grid_text(grid: Grid | None) -> str:
    if grid is None:
        return "none"
    return (f"{grid.width} x {grid.height} cells of {grid.cell_m:g} m from "
            f"({grid.x0_m:g}, {grid.y0_m:g}) m")


def _changes(what: str, a: dict, b: dict, keys=None) -> list[str]:
    """``what key: a -> b`` for every key (of ``keys``, default all) whose value differs
    (missing shown as None)."""
    return [f"{what} {k}: {a.get(k)} -> {b.get(k)}"
            for k in sorted(set(a) | set(b) if keys is None else keys) if a.get(k) != b.get(k)]


def bundle_differences(a: MapBundle, b: MapBundle) -> list[str]:
    """Lines describing how bundle ``b`` differs from bundle ``a``; empty when they are the
    same bundle (same id).

    Covered: site, floor or kind (a warning line first), software version, build settings
    (seed, build time, data end time, every build parameter), the floor plan's files (by
    name and sha256), smoothing and coverage, source
    walks (shared, added, removed, and re-ingested: same trace id with other content),
    members, grid (size, cell and origin), layers (added, removed, unit, kind or description
    changed, and the mean and largest absolute change of their values cell by cell when the
    grids are equal; angles in deg wrapped to +-180).
    """
    ma, mb = a.manifest, b.manifest
    if ma["bundle_id"] == mb["bundle_id"]:
        return []
    out = []
    if (ma["site_id"], ma.get("floor_id"), ma.get("kind")) != \
            (mb["site_id"], mb.get("floor_id"), mb.get("kind")):
        out.append("warning: these bundles are of different sites, floors or kinds; what "
                   "follows compares unrelated maps")
    out += _changes("manifest", ma, mb, ("software_version", "floor_name"))
    pa_, pb = ma["build"].get("params", {}), mb["build"].get("params", {})
    out += _changes("build", ma["build"], mb["build"],  # a key that is a parameter: below
                    (set(ma["build"]) | set(mb["build"]))
                    - {"params", "source_walks", "floor_plan"} - set(pa_) - set(pb))
    plan_a, plan_b = plan_text(ma), plan_text(mb)
    if plan_a != plan_b:
        out.append(f"floor plan: {plan_a} -> {plan_b}")
    out += _changes("param", pa_, pb)
    la, lb = metric_lines(ma), metric_lines(mb)
    for key in sorted(set(la) | set(lb)):
        if la.get(key) != lb.get(key):
            out.append(f"{la.get(key, f'{key}: none')}\n  -> {lb.get(key, f'{key}: none')}")
    wa = {w["trace_id"]: w.get("sha256") for w in ma["build"].get("source_walks", [])}
    wb = {w["trace_id"]: w.get("sha256") for w in mb["build"].get("source_walks", [])}
    shared = wa.keys() & wb.keys()
    changed = sorted(t for t in shared if wa[t] != wb[t])
    out.append(f"walks: {len(shared) - len(changed)} shared, {len(changed)} changed content, "
               f"{len(wb.keys() - wa.keys())} added, {len(wa.keys() - wb.keys())} removed")
    out += [f"walk {t}: content changed (sha256 {str(wa[t])[:12]} -> {str(wb[t])[:12]})"
            for t in changed]
    for name in sorted(set(ma["members"]) | set(mb["members"])):
        if ma["members"].get(name) != mb["members"].get(name):
            where = ("changed" if name in ma["members"] and name in mb["members"]
                     else f"only in {'a' if name in ma['members'] else 'b'}")
            out.append(f"member {name}: {where}")
    if a.grid != b.grid:
        out.append(f"grid: {_grid_text(a.grid)} -> {_grid_text(b.grid)} (layers not compared "
                   "cell by cell)")
    layers_a, layers_b = ma.get("layers", {}), mb.get("layers", {})
    for name in sorted(set(layers_a) | set(layers_b)):
        if name not in layers_a or name not in layers_b:
            out.append(f"layer {name}: only in {'a' if name in layers_a else 'b'}")
            continue
        out += _changes(f"layer {name}", layers_a[name], layers_b[name],
                        ("unit", "kind", "description"))
        if a.grid != b.grid or a.grid is None:
            continue
        d = np.asarray(b.layers[name], float) - np.asarray(a.layers[name], float)
        if layers_a[name]["kind"] == "angle":
            d = (d + 180) % 360 - 180
        ok = np.isfinite(d)
        if ok.any() and np.abs(d[ok]).max() > 0:
            out.append(f"layer {name}: mean abs change {np.abs(d[ok]).mean():.3f} "
                       f"{layers_a[name]['unit']}, max {np.abs(d[ok]).max():.3f}")
    return out
