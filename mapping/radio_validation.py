"""The radio part of ``indoormap validate``: held-out Wi-Fi/BLE positioning, floor accuracy and a
Cramer-Rao style bound over the bundle's fingerprint map.

- **Held-out positioning** (:func:`heldout_radio`, also behind ``benchmarks/wifi_accuracy.py``):
  the floor's walks from the survey store, leave-one-walk-out (grouped ``folds``-fold by walk
  when the floor has more walks than ``max_lowo_walks``); per fold the radio maps are rebuilt
  from the training walks as ``indoormap build`` does (device table, AP selection, reference
  points; here over this floor only) and the held-out scans located with
  :func:`mapping.matching.default_matcher`, each scan on its own and with its walk's other
  scans (:func:`mapping.matching.default_walk_matcher`). Errors against the processed scan
  positions.
- **Floor accuracy**: the cross-validated accuracy stored in the site bundle (``_site`` beside
  the floor bundle) when there is one; the floor model is a site-level product.
- **Bound**: per cell the radio position bound ``sqrt(trace(J^-1))`` (m), with the Fisher
  information ``J = sum_a grad(mu_a) grad(mu_a)^T / sigma_a^2`` of the mean RSSI fields
  ``mu_a`` (dBm, Gaussian-smoothed from the reference points, ``smooth_m``) and ``sigma_a`` the
  transmitter's median standard deviation at its reference points (at least ``min_sd_db``).
  Only cells within ``smooth_m`` of a reference point get a value. A bound, not a prediction:
  it ignores missed detections and the kNN's own bias, so real errors are larger.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from localize.bundle import Grid, MapBundle
from localize.radio_match import WalkSmoothing

from .fingerprints import FingerprintDB
from .matching import default_matcher
from .radio_build import RadioParams
from .radio_scans import scan_set

if TYPE_CHECKING:  # an annotation only
    from survey.store import SurveyStore

__all__ = ["RadioValidationParams", "heldout_radio", "radio_bound", "radio_summary", "walk_folds"]


@dataclass(frozen=True)
class RadioValidationParams:
    """Parameters of :func:`radio_summary` (m, dB)."""

    max_lowo_walks: int = 60
    folds: int = 10
    bound_cell_m: float = 2.0
    smooth_m: float = 2.0
    min_sd_db: float = 3.0
    seed: int = 0


def _db_of(bundle: MapBundle, kind: str) -> FingerprintDB | None:
    names = {n: f"{kind}_{n}" for n in ("rp", "fp", "meta")}
    if not all(bundle.has_table(t) for t in names.values()):
        return None
    return FingerprintDB.from_tables({n: bundle.table(t).to_pandas() for n, t in names.items()})


def radio_bound(db: FingerprintDB, grid: Grid, mask: NDArray[np.bool_], *,
                cell_m: float = 2.0, smooth_m: float = 2.0, min_sd_db: float = 3.0
                ) -> NDArray[np.float64]:
    """Cramer-Rao style position bound (m) per cell of ``grid`` (see the module docstring);
    NaN outside ``mask`` and far from reference points. Shape ``grid.shape``."""
    step = max(1, int(round(cell_m / grid.cell_m)))
    h, w = grid.shape
    hc, wc = -(-h // step), -(-w // step)
    cm = grid.cell_m * step
    xc = grid.x0_m + (np.arange(wc) + 0.5) * cm
    yc = grid.y0_m + (np.arange(hc) + 0.5) * cm
    gx, gy = np.meshgrid(xc, yc)
    cells = np.column_stack([gx.ravel(), gy.ravel()])
    dense = db.dense()
    from scipy.spatial import cKDTree

    tree = cKDTree(dense.xy_m)
    pairs = cKDTree(cells).sparse_distance_matrix(tree, 2.5 * smooth_m, output_type="coo_matrix")
    from scipy import sparse

    wgt = sparse.csr_matrix((np.exp(-pairs.data ** 2 / (2 * smooth_m ** 2)),
                             (pairs.row, pairs.col)), shape=(len(cells), len(dense.xy_m)))
    near = np.asarray(wgt.sum(axis=1)).ravel()
    covered = near > np.exp(-0.5)  # within about one smoothing length of a reference point
    jxx = np.zeros(len(cells))
    jxy = np.zeros(len(cells))
    jyy = np.zeros(len(cells))
    var = np.where(np.isfinite(dense.var_db2), dense.var_db2, np.inf)
    known = np.isfinite(var).any(axis=0)
    sd = np.full(len(dense.aps), min_sd_db)
    if known.any():  # median over the reference points that have a variance
        v = np.where(np.isinf(var[:, known]), np.nan, var[:, known])
        sd[known] = np.sqrt(np.nanmedian(v, axis=0))
    sd = np.maximum(sd, min_sd_db)
    for a0 in range(0, len(dense.aps), 256):
        a1 = min(a0 + 256, len(dense.aps))
        heard = np.isfinite(dense.mean_dbm[:, a0:a1])
        mean = np.where(heard, dense.mean_dbm[:, a0:a1], 0.0)
        num = wgt @ mean
        den = wgt @ heard.astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            mu = np.where(den > 0.5, num / den, np.nan).reshape(hc, wc, a1 - a0)
        dmy, dmx = np.gradient(mu, cm, axis=(0, 1))
        dmx = np.nan_to_num(dmx.reshape(-1, a1 - a0)) / sd[a0:a1]
        dmy = np.nan_to_num(dmy.reshape(-1, a1 - a0)) / sd[a0:a1]
        jxx += (dmx * dmx).sum(axis=1)
        jxy += (dmx * dmy).sum(axis=1)
        jyy += (dmy * dmy).sum(axis=1)
    det = jxx * jyy - jxy * jxy
    with np.errstate(invalid="ignore", divide="ignore"):
        bound = np.sqrt((jxx + jyy) / det)
    bound = np.where(covered & np.isfinite(bound) & (det > 0), bound, np.nan).reshape(hc, wc)
    full = np.repeat(np.repeat(bound, step, axis=0), step, axis=1)[:h, :w]
    return np.where(mask, full, np.nan)


def walk_folds(walks: ArrayLike, folds: int, seed: int = 0) -> list[list[str]]:
    """Walk groups for held-out evaluation: one walk per group (``folds`` 0 or at least the
    number of walks), else ``folds`` groups of walks shuffled with ``seed``."""
    walks = np.unique(np.asarray(walks).astype(str))
    if folds and folds < len(walks):
        rng = np.random.default_rng(seed)
        fold_of = dict(zip(rng.permutation(walks), np.arange(len(walks)) % folds))
        return [[w for w in walks if fold_of[w] == k] for k in range(folds)]
    return [[w] for w in walks]


def heldout_radio(obs: dict[str, pd.DataFrame], device_of: pd.Series, floors: list[str],
                  groups: list[list[str]], *, params: RadioParams | None = None,
                  on_fold: Callable | None = None, progress: Callable[[str], None] | None = None,
                  with_positions: bool = False) -> dict:
    """Held-out Wi-Fi/BLE position errors of the shipped pipeline (the one implementation
    behind ``validate`` and ``benchmarks/wifi_accuracy.py``).

    For every group of walks: the site's radio maps are rebuilt from the other walks
    (:func:`mapping.radio_build.site_radio`: device table, AP selection, reference points),
    the held-out walks' RSSI is mapped through the device table, and every held-out scan is
    located with :func:`mapping.matching.default_matcher`, on its own (``kind``) and with
    its walk's other scans (``"<kind> walk"``, :func:`mapping.matching.default_walk_matcher`).

    Parameters
    ----------
    obs : dict
        Kind -> observation table of the site's floors (:func:`site_observations`).
    device_of : Series
        Phone model per trace id.
    floors : list of str
    groups : list of list of str
        Held-out walk groups (:func:`walk_folds`).
    params : RadioParams, optional
        Default: the build's, without the floor model.
    on_fold : callable, optional
        ``on_fold(held, radio, test_obs)`` after every fold (``test_obs``: kind -> the held-out
        rows, device-calibrated), for extra measurements.

    Returns
    -------
    dict
        ``(floor, kind)`` and ``(floor, kind + " walk")`` -> errors (m) of the held-out scans
        against their processed
        positions, NaN for scans without a known transmitter; with ``with_positions``
        ``(errors, xy_m)``, ``xy_m`` (S, 2) the scans' processed positions (m).
    """
    from .radio_build import calibrated, site_radio

    params = params or RadioParams(floor_model=False, floor_cv_folds=0)
    say = progress or (lambda msg: None)
    trace = {k: o["trace_id"].to_numpy().astype(str) for k, o in obs.items()}
    out: dict[tuple[str, str], list] = {}
    for i, held in enumerate(groups):
        test = {k: np.isin(trace[k], held) for k in obs}
        radio = site_radio({k: o[~test[k]] for k, o in obs.items()}, device_of, floors,
                           params=params)
        test_obs = {k: calibrated(o[test[k]], device_of, radio.devices) if k == "wifi"
                    and len(radio.devices) else o[test[k]] for k, o in obs.items()}
        for (floor, kind), db in sorted(radio.fingerprints.items()):
            t = test_obs[kind]
            t = t[t["floor"].to_numpy() == floor]
            if len(t) == 0:
                continue
            scans = scan_set(t)
            matcher = default_matcher(kind=kind).fit(db)
            for key, smoothing in ((kind, None), (f"{kind} walk", WalkSmoothing())):
                matcher.walk_smoothing = smoothing
                res = matcher.predict(scans)
                out.setdefault((floor, key), []).append(
                    (np.linalg.norm(res.xy_m - scans.xy_m, axis=1), scans.xy_m))
        if on_fold is not None:
            on_fold(held, radio, test_obs)
        if len(groups) <= 10 or (i + 1) % 10 == 0 or i + 1 == len(groups):
            say(f"radio fold {i + 1}/{len(groups)}")  # leave-one-walk-out: every 10th
    if with_positions:
        return {key: (np.concatenate([e for e, _ in v]), np.concatenate([xy for _, xy in v]))
                for key, v in out.items()}
    return {key: np.concatenate([e for e, _ in v]) for key, v in out.items()}


def _site_floor_model(bundle: MapBundle, key: str = "floor_model") -> dict | None:
    """The floor model's metrics (``key``: ``floor_model``, or ``ble_floor_model`` for the
    BLE model beside a Wi-Fi one) of the site bundle beside ``bundle``: ``OUT/_site`` of a
    build, or the current ``REG/<site>/_site`` of a registry version."""
    from localize.bundle import read_manifest, registry_current

    from .registry import SITE_BUNDLE

    site = bundle.path.parent / SITE_BUNDLE
    if bundle.path.parent.name == "versions":  # REG/<site>/<floor>/versions/<id>
        found = registry_current(bundle.path.parents[2] / SITE_BUNDLE)
        site = found[0] if found else site
    if not (site / "manifest.json").exists():
        return None
    m = read_manifest(site)
    if m.get("kind") != "site" or m.get("site_id") != bundle.site_id:
        return None
    return (m.get("metrics") or {}).get(key)


def radio_summary(bundle: MapBundle, store: SurveyStore | str | Path | None, floor: str,
                  site: str | None, *,
                  params: RadioValidationParams = RadioValidationParams(),
                  leave_out: Collection[str] = (),
                  progress: Callable[[str], None] | None = None) -> dict:
    """The radio section's figures (JSON-able) plus ``arrays`` for the report's plots.

    ``store``: the survey store the bundle was built from, or None (then only the bound and
    the site's floor accuracy are reported). ``leave_out``: trace ids of the store's walks that
    the bundle was not built from; the held-out folds do not read them. ``progress`` receives
    a message per held-out fold (the maps are rebuilt for each).
    """
    from .radio_build import site_observations

    out: dict = {"kinds": {}, "arrays": {}}
    errors, split = None, ""
    if store is not None:
        from survey.store import SurveyStore

        st = store if isinstance(store, SurveyStore) else SurveyStore.open(store)
        obs = {k: site_observations(st, site, [floor], k, exclude_walks=leave_out)
               for k in ("wifi", "ble")}
        walks = np.unique(np.concatenate([o["trace_id"].to_numpy().astype(str)
                                          for o in obs.values() if len(o)] or [np.empty(0)]))
        if len(walks) >= 2:
            folds = 0 if len(walks) <= params.max_lowo_walks else params.folds
            split = ("leave-one-walk-out" if folds == 0 else
                     f"grouped {params.folds}-fold by walk")
            device_of = st.catalog().set_index("trace_id")["device_model"].astype(str)
            errors = heldout_radio({k: o for k, o in obs.items() if len(o)}, device_of, [floor],
                                   walk_folds(walks, folds, params.seed), with_positions=True,
                                   progress=progress)
    fm = _site_floor_model(bundle)
    out["floor_model"] = fm
    out["ble_floor_model"] = None if fm is None else _site_floor_model(bundle,
                                                                       "ble_floor_model")
    out["floor_accuracy"] = None if fm is None else fm.get("cv_scan_accuracy")
    if fm is None:
        out["floor_note"] = "no site bundle (_site) beside this floor bundle: floor accuracy " \
                            "not known"
    first = None
    for kind in ("wifi", "ble"):
        db = _db_of(bundle, kind)
        if db is None:
            out["kinds"][kind] = {"available": False, "reason": f"the bundle has no {kind} "
                                                                "fingerprints"}
            continue
        k_out: dict = {"available": True, "reference_points": len(db),
                       "transmitters": int(len(db.aps)), "cell_m": db.cell_m}
        bound = radio_bound(db, bundle.grid, np.asarray(bundle.mask, bool),
                            cell_m=params.bound_cell_m, smooth_m=params.smooth_m,
                            min_sd_db=params.min_sd_db)
        fin = bound[np.isfinite(bound)]
        k_out["bound_m"] = {"median": float(np.median(fin)) if fin.size else None,
                            "p90": float(np.percentile(fin, 90)) if fin.size else None,
                            "cells": int(fin.size)}
        if errors is not None and (floor, kind) in errors:
            e, xy = errors[(floor, kind)]
            out["arrays"][f"{kind}_error_points"] = (xy[np.isfinite(e)], e[np.isfinite(e)])
            e = e[np.isfinite(e)]
            if e.size:
                k_out.update(split=split, scans=int(e.size),
                             median_error_m=float(np.median(e)),
                             p80_error_m=float(np.percentile(e, 80)),
                             mean_error_m=float(e.mean()))
                out["arrays"][f"{kind}_errors_m"] = e
            walk_e, _ = errors.get((floor, f"{kind} walk"), (np.empty(0), None))
            walk_e = walk_e[np.isfinite(walk_e)]
            if walk_e.size:
                k_out.update(walk_median_error_m=float(np.median(walk_e)),
                             walk_p80_error_m=float(np.percentile(walk_e, 80)))
                out["arrays"][f"{kind}_walk_errors_m"] = walk_e
        out["kinds"][kind] = k_out
        if first is None:
            first = kind
            out["arrays"]["radio_bound_m"] = bound
    if first is not None:
        main = out["kinds"][first]
        out["primary_kind"] = first
        out["median_error_m"] = main.get("median_error_m")
        out["p80_error_m"] = main.get("p80_error_m")
        for name in ("errors_m", "walk_errors_m"):
            if f"{first}_{name}" in out["arrays"]:
                out["arrays"][f"radio_{name}"] = out["arrays"][f"{first}_{name}"]
    return out
