"""Shared machinery of the localizer benchmarks (accuracy, tuning): walks, folds, maps, runs.

Two data sources:

- a simulated site (``survey.sim``): truth at every step; maps are either the *truth bundle*
  (the simulator's field sampled on a 0.25 m grid, :mod:`survey.sim.truth_bundle`) or bundles
  *built* by ``mapping.build.build_floor`` from the survey walks of the other folds;
- the real ILC traces (``../shared/ilc/site1``): errors at the recorded waypoints only; maps
  built from the other folds' walks.

Folds are 5-fold by walk (a seeded permutation of the sorted trace ids). The radio positioner of
a fold is the fold bundle's Wi-Fi fingerprints (:func:`fold_radio`, what ``indoormap localize``
uses), or a kNN over the training walks' scans, positioned by the simulator's truth (sim) or by
time interpolation between waypoints (real, as the ILC kNN baseline), for bundles without
fingerprints (truth maps) or on request.
"""

from __future__ import annotations

import functools
import hashlib
import json
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from localize.baselines import make_localizer
from localize.methods import PARTICLE_FILTERS
from localize.bundle import RSSI_RANGE_DBM, MapBundle, load_bundle
from localize.errors import LocalizationError
from localize.evaluate import step_errors, summarize, waypoint_errors
from localize.maps import FilterMap
from localize.params import FilterParams
from localize.radio import KnnRadioPositioner
from localize.steps import RadioScan, StepSummaries
from localize.track import Track

from real_data import ILC_SITE1, REPO  # $INDOORMAP_ILC or ../shared/ilc

SHARED_SITE = ILC_SITE1

#: Methods in table order; "pdr@wp0" is PDR from the first waypoint (the ILC baseline);
#: "name[variant]" runs a method with other parameters (:data:`VARIANTS`).
ALL_METHODS = ("auto", "indoormap", "indoormap[smoothed]", "indoormap[paper]", "indoormap[weinberg]",
               "pf_no_mag", "pf_no_mag[smoothed]", "magpp_gaussian", "magicol_dtw", "pdr",
               "pdr@wp0", "radio", "align", "align[smoothed]")


def _variant(name: str, params: FilterParams) -> tuple[str, FilterParams, bool]:
    """Method, parameters and whether to smooth (offline) of a table row name."""
    if "[" not in name:
        return name, params, False
    base, variant = name[:-1].split("[")
    if variant == "paper":
        return base, FilterParams.paper_params(), False
    if variant == "weinberg":
        return base, replace(params, step_model="weinberg", genome_a_mean=0.38,
                             genome_a_sd=0.03), False
    if variant == "smoothed":
        return base, params, True
    raise ValueError(f"unknown variant {variant!r}")


@dataclass
class EvalWalk:
    """A walk ready to localize, with its references."""

    trace_id: str
    floor: str
    steps: StepSummaries
    wp_t: np.ndarray                       # recorded waypoints (ms, m)
    wp_xy: np.ndarray
    true_xy: np.ndarray | None = None      # truth at every step (simulation only)
    radio_refs: list[tuple[RadioScan, np.ndarray]] = field(default_factory=list)
    ble_scans: list[RadioScan] = field(default_factory=list)  # 2 s BLE windows


# -- walks ---------------------------------------------------------------------------------

_STEP_ARRAYS = ("t_ms", "frequency_hz", "delta_acc_ms2", "compass_deg", "turn_deg",
                "strength_ut", "azimuth_deg", "polar_deg", "attitude", "relative_heading_deg",
                "mag_offsets", "mag_strength_ut")
_SCAN_KEYS = ("slot", "t", "off", "keys", "rssi", "age")


def _scans_arrays(scans: list[RadioScan | None]) -> dict[str, np.ndarray]:
    present = [s for s in scans if s is not None]
    return {"slot": np.array([i for i, s in enumerate(scans) if s is not None], dtype=np.int64),
            "t": np.array([s.t_ms for s in present], dtype=np.int64),
            "off": np.cumsum([0] + [len(s) for s in present]).astype(np.int64),
            "keys": np.concatenate([s.keys for s in present]).astype(str) if present
            else np.empty(0, dtype="<U1"),
            "rssi": np.concatenate([s.rssi_dbm for s in present]) if present else np.empty(0),
            "age": np.concatenate([np.full(len(s), np.nan) if s.age_ms is None else s.age_ms
                                   for s in present]) if present else np.empty(0)}


def _scans_from(a: dict, n: int) -> list[RadioScan | None]:
    out: list[RadioScan | None] = [None] * n
    for j, slot in enumerate(a["slot"]):
        lo, hi = a["off"][j], a["off"][j + 1]
        out[int(slot)] = RadioScan(int(a["t"][j]), a["keys"][lo:hi], a["rssi"][lo:hi],
                                   a["age"][lo:hi])
    return out


def _save_walks(path: Path, walks: list[EvalWalk]) -> None:
    """Walks as one ``.npz`` of plain arrays (never pickles: RELIABILITY.md item 4)."""
    arrays: dict[str, np.ndarray] = {}
    meta = []
    for i, w in enumerate(walks):
        s = w.steps
        for name in _STEP_ARRAYS:
            arrays[f"{i}/{name}"] = np.asarray(getattr(s, name))
        for k, v in _scans_arrays(list(s.scans)).items():
            arrays[f"{i}/scan_{k}"] = v
        for k, v in _scans_arrays([r for r, _ in w.radio_refs]).items():
            arrays[f"{i}/ref_{k}"] = v
        arrays[f"{i}/ref_xy"] = np.array([xy for _, xy in w.radio_refs]).reshape(-1, 2)
        for k, v in _scans_arrays(list(w.ble_scans)).items():
            arrays[f"{i}/ble_{k}"] = v
        arrays[f"{i}/wp_t"], arrays[f"{i}/wp_xy"] = w.wp_t, w.wp_xy
        if w.true_xy is not None:
            arrays[f"{i}/true_xy"] = w.true_xy
        meta.append({"trace_id": w.trace_id, "floor": w.floor, "site_id": s.site_id,
                     "floor_id": s.floor_id, "floor_name": s.floor_name})
    arrays["meta"] = np.array(json.dumps(meta))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)


def _load_walks(path: Path) -> list[EvalWalk]:
    with np.load(path, allow_pickle=False) as z:
        a = {k: z[k] for k in z.files}
    out = []
    for i, m in enumerate(json.loads(str(a["meta"]))):
        cols = {name: a[f"{i}/{name}"] for name in _STEP_ARRAYS}
        n = len(cols["t_ms"])
        scans = _scans_from({k: a[f"{i}/scan_{k}"] for k in _SCAN_KEYS}, n)
        steps = StepSummaries(**cols, scans=tuple(scans), trace_id=m["trace_id"],
                              site_id=m["site_id"], floor_id=m["floor_id"],
                              floor_name=m["floor_name"])
        ref = {k: a[f"{i}/ref_{k}"] for k in _SCAN_KEYS}
        refs = _scans_from(ref, len(ref["slot"]))
        ble = {k: a[f"{i}/ble_{k}"] for k in _SCAN_KEYS}
        out.append(EvalWalk(m["trace_id"], m["floor"], steps, a[f"{i}/wp_t"], a[f"{i}/wp_xy"],
                            a.get(f"{i}/true_xy"), list(zip(refs, a[f"{i}/ref_xy"])),
                            _scans_from(ble, len(ble["slot"]))))
    return out


@functools.cache
def source_digest(*packages: str) -> str:
    """Short hash of the ``.py`` sources of ``packages`` (top-level folders of the repository):
    cached stores, walks and bundles carry it in their names, so a code change rebuilds them
    instead of silently reusing what older code made."""
    h = hashlib.sha256()
    for pkg in packages:
        for f in sorted((REPO / pkg).rglob("*.py")):
            h.update(str(f.relative_to(REPO)).encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:10]


def _cache(path: Path, make) -> list[EvalWalk]:
    """Walks from the ``.npz`` cache, or built and cached."""
    if path.exists():
        return _load_walks(path)
    walks = make()
    _save_walks(path, walks)
    return walks


def sim_site(work: Path, preset: str = "default", seed: int = 7) -> Path:
    """The simulated site (simulated once into ``work``)."""
    from survey.sim.site import SiteParams, simulate_site

    site = work / f"sim_{preset}_{seed}"
    if not (site / "truth" / "site.json").exists():
        simulate_site(SiteParams.preset_params(preset, seed=seed), site, overwrite=True)
    return site


def sim_walks(site: Path, floor: str, work: Path) -> list[EvalWalk]:
    """Walks of a simulated floor with truth at every step and truth-positioned scans."""
    def make():
        import pandas as pd

        from survey.step_summaries import ble_scans_of, scans_of, step_summaries, waypoints_of
        from survey.trace_reader import read_trace

        sj = json.loads((site / "truth" / "site.json").read_text())
        out = []
        for w in sj["walks"]:
            if w["floor"] != floor:
                continue
            trace = read_trace(site / w["trace_path"])
            steps = step_summaries(trace)
            truth = pd.read_parquet(site / w["truth_path"])
            tt = truth["t_ms"].to_numpy(np.float64)

            def at(t, truth=truth, tt=tt):
                t = np.asarray(t, dtype=np.float64)
                return np.column_stack([np.interp(t, tt, truth["x_m"]),
                                        np.interp(t, tt, truth["y_m"])])

            wp_t, wp_xy = waypoints_of(trace)
            refs = [(s, at([s.t_ms])[0]) for s in scans_of(trace)]
            out.append(EvalWalk(w["trace_id"], floor, steps, wp_t, wp_xy, at(steps.t_ms),
                                refs, ble_scans_of(trace)))
        return out

    return _cache(work / "cache" / f"{site.name}_{floor}_walks2_{source_digest('survey')}.npz",
                  make)


def real_walks(floor_dir: Path, work: Path) -> list[EvalWalk]:
    """Walks of a real floor; scans positioned by time interpolation between waypoints."""
    def make():
        from survey.errors import IndoormapError
        from survey.step_summaries import ble_scans_of, scans_of, step_summaries, waypoints_of
        from survey.trace_reader import find_trace_files, read_trace

        out = []
        for path in find_trace_files([floor_dir / "path_data_files"]):
            try:
                trace = read_trace(path)
            except IndoormapError as err:  # an empty or foreign file: not a walk
                print(f"  skipped {err}", file=sys.stderr)
                continue
            wp_t, wp_xy = waypoints_of(trace)
            if len(wp_t) < 2:
                continue
            try:
                steps = step_summaries(trace)
            except IndoormapError as err:
                print(f"  skip {trace.trace_id}: {err}")
                continue
            refs = []
            for s in scans_of(trace):
                if wp_t[0] <= s.t_ms <= wp_t[-1]:
                    refs.append((s, np.array([np.interp(s.t_ms, wp_t, wp_xy[:, 0]),
                                              np.interp(s.t_ms, wp_t, wp_xy[:, 1])])))
            out.append(EvalWalk(trace.trace_id, floor_dir.name, steps, wp_t, wp_xy, None,
                                refs, ble_scans_of(trace)))
        return out

    return _cache(work / "cache" / f"ilc_{floor_dir.parent.name}_{floor_dir.name}_walks2_"
                  f"{source_digest('survey')}.npz", make)


def with_ble_rssi(walks: list[EvalWalk], k: float, b: float) -> list[EvalWalk]:
    """The walks with their BLE RSSI read as a phone on another scale would: ``k * rssi + b``
    (dBm), within the range a phone reports (:data:`localize.bundle.RSSI_RANGE_DBM`). Their
    Wi-Fi is left as it is."""
    if (k, b) == (1.0, 0.0):
        return walks
    return [replace(w, ble_scans=[RadioScan(s.t_ms, s.keys,
                                            np.clip(k * s.rssi_dbm + b, *RSSI_RANGE_DBM),
                                            s.age_ms)
                                  for s in w.ble_scans]) for w in walks]


def folds_of(walks: list[EvalWalk], k: int = 5, seed: int = 0) -> list[list[str]]:
    """Test trace ids of each of ``k`` folds (a seeded permutation of the sorted ids)."""
    ids = sorted(w.trace_id for w in walks)
    perm = np.random.default_rng(seed).permutation(len(ids))
    return [sorted(ids[i] for i in perm[f::k]) for f in range(k)]


#: Options of the benchmarks' kNN positioner (``likelihood_sigma_m=0``: the filter's radio
#: update is a Gaussian around the fix instead of the k-reference mixture).
RADIO_OPTIONS: dict = {"k": 5}


def fold_radio(kind: str, walks: list[EvalWalk], test: list[str], bundle: MapBundle):
    """The radio model of a fold: ``"bundle"``, the bundle's Wi-Fi fingerprints (what
    ``indoormap localize`` uses, without its per-phone RSSI calibration: the ILC walks share
    one phone model, and calibrating online changed the fixes' errors by 0.01 m in session
    19; bundles without fingerprints, e.g. truth maps, fall back to the kNN), or ``"knn"``, a
    kNN over the training walks' scans (BLE: :func:`run_fold`'s ``ble``)."""
    if kind not in ("bundle", "knn"):
        raise ValueError(f"radio must be 'bundle' or 'knn', got {kind!r}")
    if kind == "bundle":
        from localize.fingerprint_positioner import FingerprintPositioner

        pos = FingerprintPositioner.from_bundle(bundle, "wifi")
        if pos is not None:
            return pos
    return radio_for(walks, set(test))


def radio_for(walks: list[EvalWalk], exclude: set[str]) -> KnnRadioPositioner | None:
    refs = [(s, xy) for w in walks if w.trace_id not in exclude for s, xy in w.radio_refs]
    if not refs:
        return None
    return KnnRadioPositioner.from_scans(np.array([xy for _, xy in refs]),
                                         [s for s, _ in refs], **RADIO_OPTIONS)


# -- maps ----------------------------------------------------------------------------------

def truth_bundle_of(site: Path, floor: str, work: Path, cell_m: float = 0.25) -> MapBundle:
    from survey.sim.truth_bundle import truth_bundle

    target = work / "bundles" / f"{site.name}_{floor}_truth_{cell_m:g}"
    if not (target / "manifest.json").exists():
        truth_bundle(site, floor, target, cell_m=cell_m, overwrite=True)
    return load_bundle(target)


def builder_available() -> bool:
    try:
        import mapping.build  # noqa: F401
    except ImportError:
        return False
    return True


def processed_store(name: str, floor_dirs: list[Path], work: Path):
    """A survey store with the floors' traces ingested and processed (made once)."""
    from mapping.floorplan import read_floor_plan
    from survey.ingest import ingest
    from survey.process_store import process_store, processed_catalog
    from survey.store import SurveyStore

    path = work / "stores" / f"{name}_{source_digest('survey')}"
    done = path / ".processed"
    if not done.exists():
        t0 = time.time()
        ingest([f / "path_data_files" for f in floor_dirs], path)
        store = SurveyStore.open(path)
        cat = store.traces()
        reach = {}
        for f in floor_dirs:
            plan = read_floor_plan(f)
            for site in cat.loc[cat["floor"] == f.name, "site"].unique():
                reach[(site, f.name)] = plan.reachable
        process_store(store, reachable=reach)
        done.write_text(f"{time.time() - t0:.0f} s\n")
    cat = processed_catalog(path)
    for _, walk in cat[cat["status"] != "ok"].iterrows():  # left out of every map: say so
        print(f"note: {walk['floor']} walk {walk['trace_id']} {walk['status']} in processing: "
              f"{walk['reason']}", file=sys.stderr)
    return SurveyStore.open(path)


def built_bundle(store, floor_dir: Path, exclude: set[str], work: Path, tag: str,
                 cell_m: float = 0.5) -> MapBundle:
    """A bundle of the floor built by ``mapping.build`` without the ``exclude`` walks."""
    from mapping.build import BuildParams, build_floor
    from mapping.bundle_writer import write_bundle
    from mapping.floorplan import read_floor_plan

    key = hashlib.sha256((source_digest("survey", "mapping") + ","
                          + ",".join(sorted(exclude))).encode()).hexdigest()[:12]
    target = work / "bundles" / f"{tag}_{floor_dir.name}_built_{cell_m:g}_{key}"
    if not (target / "manifest.json").exists():
        plan = read_floor_plan(floor_dir)
        content = build_floor(store, plan, floor=floor_dir.name, exclude_walks=exclude,
                              params=BuildParams(cell_m=cell_m, build_time="bench"))
        write_bundle(target, content, overwrite=True)
    return load_bundle(target)


# -- runs ----------------------------------------------------------------------------------

@dataclass
class RunResult:
    """Errors of every method, walk by walk (``walks[method][i]`` is the trace id of
    ``wp[method][i]`` and ``step[method][i]``). ``fallback`` holds the walks that had no radio
    fix and started at their first waypoint, i.e. at the truth: :meth:`summary` leaves them
    out unless asked, so that a rule which takes a walk's every fix away cannot gain by it."""

    wp: dict[str, list[np.ndarray]] = field(default_factory=dict)
    step: dict[str, list[np.ndarray]] = field(default_factory=dict)
    walks: dict[str, list[str]] = field(default_factory=dict)
    fallback: set[str] = field(default_factory=set)
    seconds: dict[str, float] = field(default_factory=dict)
    steps: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def add(self, method: str, track: Track, w: EvalWalk, seconds: float) -> None:
        self.wp.setdefault(method, []).append(waypoint_errors(track, w.wp_t, w.wp_xy))
        self.walks.setdefault(method, []).append(w.trace_id)
        if w.true_xy is not None:
            self.step.setdefault(method, []).append(step_errors(track, w.true_xy))
        self.seconds[method] = self.seconds.get(method, 0.0) + seconds
        self.steps[method] = self.steps.get(method, 0) + len(track)

    def merge(self, other: RunResult) -> None:
        for d_self, d_other in ((self.wp, other.wp), (self.step, other.step),
                                (self.walks, other.walks)):
            for k, v in d_other.items():
                d_self.setdefault(k, []).extend(v)
        self.fallback |= other.fallback
        for k, v in other.seconds.items():
            self.seconds[k] = self.seconds.get(k, 0.0) + v
            self.steps[k] = self.steps.get(k, 0) + other.steps[k]
        self.notes.extend(other.notes)

    def errors(self, method: str, what: str = "wp", fallback: bool = False
               ) -> list[tuple[str, np.ndarray]]:
        """``(trace id, errors (m))`` of every walk ``method`` ran, at the waypoints (``wp``)
        or at every step (``step``); the :attr:`fallback` walks only with ``fallback``."""
        d = self.wp if what == "wp" else self.step
        return [(t, e) for t, e in zip(self.walks.get(method, []), d.get(method, []))
                if fallback or t not in self.fallback]

    def summary(self, method: str, what: str = "wp", fallback: bool = False
                ) -> dict[str, float]:
        """Median, p80, mean and count of the errors (:meth:`errors`)."""
        e = [e for _, e in self.errors(method, what, fallback)]
        return summarize(np.concatenate(e) if e else np.empty(0))


def run_fold(walks: list[EvalWalk], test_ids: list[str], bundle: MapBundle, methods,
             params: FilterParams, *, start: str = "wifi", seed: int = 0,
             radio=None, ble: bool = False) -> RunResult:
    """Localize the test walks of one fold with every method.

    ``start``: ``"wifi"`` (first radio fix of the walk; walks without one start at their first
    waypoint, noted), ``"waypoint"`` (first waypoint) or ``"truth"`` (true position, sim).
    ``ble``: every walk as a phone that logs no Wi-Fi (an iPhone) runs it: its steps carry its
    BLE windows and its radio is the bundle's BLE fingerprints calibrated online for it
    (:func:`localize.walk_radio.radio_for_walk`, what ``indoormap localize`` does for such a
    walk); ``radio`` is then ignored.
    """
    from localize.walk_radio import radio_for_walk

    res = RunResult()
    fmaps: dict[str, FilterMap] = {}
    for w in walks:
        if w.trace_id not in test_ids:
            continue
        walk_radio = radio
        if ble:
            walk_radio = radio_for_walk(bundle, None, w.ble_scans, kind="ble")[0]
            w = replace(w, steps=w.steps.with_scans(w.ble_scans))
        wp0 = (float(w.wp_xy[0, 0]), float(w.wp_xy[0, 1]))
        start_xy, t_start = None, None
        if start == "truth" and w.true_xy is not None:
            start_xy = tuple(w.true_xy[0])
        elif start == "waypoint":
            start_xy, t_start = wp0, float(w.wp_t[0])
        elif start == "wifi":
            fix = None
            if walk_radio is not None and w.steps.scans is not None:
                fix = next((f for s in w.steps.scans if s is not None
                            and (f := walk_radio.locate(s)) is not None), None)
            if fix is None:
                start_xy, t_start = wp0, float(w.wp_t[0])
                res.fallback.add(w.trace_id)
                res.notes.append(f"{w.trace_id}: no {'BLE' if ble else 'Wi-Fi'} fix, started at "
                                 "the first waypoint (left out of the table)")
        for m in methods:
            name, p, smooth = _variant(m, params)
            s_xy, t0 = start_xy, t_start
            if m == "pdr@wp0":
                name, s_xy, t0 = "pdr", wp0, float(w.wp_t[0])
            try:
                if name in PARTICLE_FILTERS:
                    if m not in fmaps:  # pack the layers once per fold and row
                        fmaps[m] = make_localizer(name, bundle, p, rng=seed).fmap
                    loc = make_localizer(name, bundle, p, radio=walk_radio, rng=seed,
                                         fmap=fmaps[m])
                else:
                    loc = make_localizer(name, bundle, p, radio=walk_radio, rng=seed,
                                         magnetometer=w.steps.has_magnetometer)
                t = time.process_time()
                track = loc.run(w.steps, start_xy=s_xy,
                                start_t_ms=t0 if t0 is not None and t0 < w.steps.t_ms[0]
                                else None, smooth=smooth)
                res.add(m, track, w, time.process_time() - t)
            except LocalizationError as err:
                res.notes.append(f"{w.trace_id} {m}: {err}")
    return res


def print_table(title: str, res: RunResult, methods, what=("wp", "step")) -> None:
    print(f"\n{title}")
    head = f"{'method':<20}"
    for w in what:
        label = "waypoints" if w == "wp" else "every step"
        head += f"| {label + ' (m): median  p80  mean':<36}"
    print(head + "| ms/step")
    for m in methods:
        if m not in res.wp:
            continue
        line = f"{m:<20}"
        for w in what:
            s = res.summary(m, w)
            line += f"| n={s['n']:<6} {s['median']:>6.2f} {s['p80']:>6.2f} {s['mean']:>6.2f}" \
                    f"{'':<6}" if s["n"] else f"| {'-':<35}"
        ms = 1000.0 * res.seconds.get(m, 0.0) / max(res.steps.get(m, 1), 1)
        print(line + f"| {ms:.2f}")
    if res.fallback:
        ran = {t for ts in res.walks.values() for t in ts}
        print(f"({len(res.fallback)} of {len(ran)} walks had no radio fix and started at their "
              "first waypoint, the truth: left out of the rows above)")
