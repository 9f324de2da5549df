"""The particle-filter localizer on simulated walks with a known map."""

from __future__ import annotations

import copy
import dataclasses
import json
import re
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from localize_fixtures import f1_bundle, sim_walks, truth_bundles  # noqa: F401  (fixtures)

from localize.baselines import METHODS, make_localizer
from localize.methods import auto_method
from localize.bundle import load_bundle
from localize.engine import MultiUserEngine
from localize.errors import LocalizationError
from localize.evaluate import step_errors, summarize, waypoint_errors
from localize.filter import Localizer
from localize.floors import SiteMaps
from localize.params import FeatureParams, FilterParams
from localize.radio import KnnRadioPositioner
from localize.stepper import StepInputs

RUNTIME_MODULES = ["localize", "localize.bundle", "localize.errors", "localize.steps",
                   "localize.maps", "localize.params", "localize.particles", "localize.weights",
                   "localize.update", "localize.resample", "localize.stepper", "localize.filter",
                   "localize.baselines", "localize.engine", "localize.align_engine",
                   "localize.ticks", "localize.align", "localize.radio", "localize.floors",
                   "localize.track", "localize.evaluate", "localize.start", "localize.walk_radio",
                   "localize.plots", "localize.cli_common", "localize.cli"]


def test_runtime_imports_no_scipy_pandas_sklearn():
    code = ("import sys\n"
            + "".join(f"import {m}\n" for m in RUNTIME_MODULES)
            + "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
              "('scipy', 'pandas', 'sklearn', 'shapely', 'numba', 'matplotlib'))\n"
              "print(','.join(bad))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "", f"runtime pulled in: {out.stdout}"


def _f1(sim_walks):  # noqa: F811
    return [w for w in sim_walks if w.floor == "F1"]


def test_same_seed_same_trajectory(f1_bundle, sim_walks):  # noqa: F811
    w = _f1(sim_walks)[0]
    runs = [Localizer(f1_bundle, FilterParams(), rng=11).run(w.steps, start_xy=w.start_xy)
            for _ in range(2)]
    assert np.array_equal(runs[0].x_m, runs[1].x_m)
    assert np.array_equal(runs[0].y_m, runs[1].y_m)
    other = Localizer(f1_bundle, FilterParams(), rng=12).run(w.steps, start_xy=w.start_xy)
    assert not np.array_equal(runs[0].x_m, other.x_m)
    # an injected generator is used as is
    g1, g2 = np.random.default_rng(5), np.random.default_rng(5)
    a = Localizer(f1_bundle, rng=g1).run(w.steps, start_xy=w.start_xy)
    b = Localizer(f1_bundle, rng=g2).run(w.steps, start_xy=w.start_xy)
    assert np.array_equal(a.x_m, b.x_m)
    # the track as a table for a notebook: the written columns, with where it came from
    frame = runs[0].to_frame()
    assert list(frame.columns) == runs[0].to_arrow().column_names and len(frame) == len(w.steps)
    assert np.array_equal(frame["x_m"].to_numpy(), runs[0].x_m)
    assert frame.attrs["trace_id"] == w.steps.trace_id and frame.attrs["method"] == "indoormap"
    fractional = 1000.7 + 500 * np.arange(len(frame))  # streamed steps' times
    streamed = dataclasses.replace(runs[0], t_ms=fractional)
    want = 1001 + 500 * np.arange(len(frame), dtype=np.int64)
    assert np.array_equal(streamed.to_columns()["t_ms"], want)  # rounded, not cut
    # the table's metadata is the frame's, as text (a written track says where it started)
    meta = runs[0].to_arrow().schema.metadata
    assert {k.decode() for k in meta} == set(frame.attrs)
    assert float(meta[b"start_x_m"]) == frame.attrs["start_x_m"] == runs[0].start.x_m
    assert meta[b"n_recoveries"] == str(runs[0].n_recoveries).encode()
    assert meta[b"trace_id"] == w.steps.trace_id.encode()
    numpy_start = dataclasses.replace(runs[0], start=dataclasses.replace(
        runs[0].start, x_m=np.float32(1.5), y_m=np.int64(2)))  # a caller's radio model's
    assert numpy_start.to_arrow().schema.metadata[b"start_x_m"] == b"1.5"


def test_streaming_equals_batch(f1_bundle, sim_walks):  # noqa: F811
    w = _f1(sim_walks)[1]
    batch = Localizer(f1_bundle, rng=3).run(w.steps, start_xy=w.start_xy)
    loc = Localizer(f1_bundle, rng=3)
    loc.start(*w.start_xy, t_ms=w.steps.t_ms[0] - 500.0)
    xs = [loc.step(s).x_m for s in w.steps]
    assert np.array_equal(xs, batch.x_m)


def test_converges_on_simulated_walks(f1_bundle, sim_walks):  # noqa: F811
    """Truth map, start within 2 m of the truth: the default filter tracks every walk.

    Bound: median per-step error below 1.0 m and p80 below 1.5 m over all F1 walks (on this
    site the filter achieves ~0.4 m median, PDR ~2 m; the walker strays 0.6-1.8 m from the
    waypoint lines, so PDR errors grow along the walk while the filter's do not)."""
    errs, pdr = [], []
    for w in _f1(sim_walks):
        t = Localizer(f1_bundle, FilterParams(), rng=1).run(w.steps, start_xy=w.start_xy)
        e = step_errors(t, w.true_xy)
        assert np.median(e) < 1.5, w.trace_id
        errs.append(e)
        p = make_localizer("pdr", f1_bundle).run(w.steps, start_xy=w.start_xy)
        pdr.append(step_errors(p, w.true_xy))
    s, sp = summarize(np.concatenate(errs)), summarize(np.concatenate(pdr))
    assert s["median"] < 1.0 and s["p80"] < 1.5, s
    assert s["median"] < 0.6 * sp["median"], (s, sp)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_every_method_runs(f1_bundle, sim_walks, method):  # noqa: F811
    walks = _f1(sim_walks)
    w = max(walks, key=lambda v: sum(s is not None for s in v.steps.scans))
    scans = [(s, xy) for v in walks if v is not w
             for s, xy in zip(v.steps.scans, v.true_xy) if s is not None]
    radio = KnnRadioPositioner.from_scans(np.array([xy for _, xy in scans]),
                                          [s for s, _ in scans])
    loc = make_localizer(method, f1_bundle, FilterParams(n_particles=100), radio=radio, rng=0)
    track = loc.run(w.steps)  # start from the first Wi-Fi fix
    assert len(track) == len(w.steps) and np.isfinite(track.x_m).all()
    assert track.method == (auto_method(f1_bundle.manifest.get("metrics") or {}).method
                            if method == "auto" else method)
    assert np.median(step_errors(track, w.true_xy)) < 15.0


def test_engine_matches_single_user_and_scales(f1_bundle, sim_walks):  # noqa: F811
    w = _f1(sim_walks)[0]
    p = FilterParams(n_particles_start=0)  # the engine keeps n_particles from the start
    ref = Localizer(f1_bundle, p, rng=9).run(w.steps, start_xy=w.start_xy)
    eng = MultiUserEngine(f1_bundle, p, rng=9)
    ids = eng.add_users([w.start_xy])
    cols = ["compass_deg", "frequency_hz", "turn_deg", "strength_ut", "azimuth_deg",
            "polar_deg", "attitude"]
    xs = []
    for i in range(len(w.steps)):
        out = eng.tick(ids, StepInputs(*(np.array([getattr(w.steps, c)[i]]) for c in cols)))
        xs.append(out.x_m[0])
    assert np.allclose(xs, ref.x_m)
    # many users of all F1 walks at once, float32 particles: every user is tracked
    walks = _f1(sim_walks)
    eng = MultiUserEngine(f1_bundle, p, rng=2, dtype=np.float32)
    ids = eng.add_users(np.array([v.start_xy for v in walks]))
    n = min(len(v.steps) for v in walks)
    est = []
    for i in range(n):
        out = eng.tick(ids, StepInputs(*(np.array([getattr(v.steps, c)[i] for v in walks])
                                         for c in cols)))
        est.append(np.column_stack([out.x_m, out.y_m]))
    est = np.stack(est, axis=1)  # (users, steps, 2)
    for k, v in enumerate(walks):
        err = np.hypot(*(est[k] - v.true_xy[:n]).T)
        assert np.median(err) < 2.0, v.trace_id
    assert eng.bytes_per_user < 40_000
    # a subset of users ticks alone; removing users keeps the others
    eng.tick(ids[:2], StepInputs(*(np.array([getattr(v.steps, c)[n - 1] for v in walks[:2]])
                                   for c in cols)))
    eng.remove_users(ids[:1])
    assert eng.n_users == len(walks) - 1
    # a user removed twice, or an id never given, is refused, and nobody is removed
    with pytest.raises(LocalizationError, match=rf"unknown user ids in remove_users: "
                                                rf"\[{ids[0]}, 99\]"):
        eng.remove_users([ids[1], ids[0], 99])
    with pytest.raises(LocalizationError, match=r"whole numbers .*nobody was removed"):
        eng.remove_users([ids[1] + 0.7])  # was taken as ids[1]
    assert eng.n_users == len(walks) - 1
    with pytest.raises(LocalizationError):
        eng.tick(ids[:1], StepInputs(*(np.zeros(1) for _ in cols)))


def test_float32_particles_are_refused_on_a_map_far_from_the_origin(f1_bundle):  # noqa: F811
    """A plan in UTM metres keeps its coordinates (northing 4,000 km): float32 particles
    there move in 25 cm steps, so the engine refuses them and says to use float64."""
    far = copy.copy(f1_bundle)
    far.grid = replace(f1_bundle.grid, x0_m=500_000.0, y0_m=4_000_000.0)
    with pytest.raises(LocalizationError, match=r"reach 4,000,025 m, where float32 "
                                                r"particles would move in steps of 0\.25 m"):
        MultiUserEngine(far, {"n_particles": 100}, dtype=np.float32)
    assert MultiUserEngine(far, {"n_particles": 100}).n_users == 0  # float64 is fine


def test_recovery_when_all_particles_die(f1_bundle, sim_walks):  # noqa: F811
    w = _f1(sim_walks)[0]
    # compass turned by 90 deg: particles walk into walls, die, and are re-drawn
    bad = w.steps.with_columns(compass_deg=(w.steps.compass_deg + 90.0) % 360.0)
    loc = Localizer(f1_bundle, FilterParams(n_particles=100), rng=0)
    track = loc.run(bad, start_xy=w.start_xy)
    assert track.n_recoveries > 0 and loc.n_recoveries == track.n_recoveries
    assert np.isfinite(track.x_m).all()
    assert f1_bundle.reachable(track.x_m, track.y_m).mean() > 0.5


# -- bad input ------------------------------------------------------------------------------

def test_walk_without_steps(f1_bundle, sim_walks):  # noqa: F811
    w = _f1(sim_walks)[0]
    empty = w.steps.with_columns(**{c: getattr(w.steps, c)[:0] for c in (
        "t_ms", "frequency_hz", "delta_acc_ms2", "compass_deg", "turn_deg", "strength_ut",
        "azimuth_deg", "polar_deg", "attitude", "relative_heading_deg")},
        mag_offsets=np.zeros(1, dtype=np.int64), mag_strength_ut=np.empty(0), scans=())
    with pytest.raises(LocalizationError, match="no steps"):
        Localizer(f1_bundle).run(empty, start_xy=w.start_xy)


def test_walk_without_magnetometer(f1_bundle, sim_walks):  # noqa: F811
    w = _f1(sim_walks)[0]
    nan = np.full(len(w.steps), np.nan)
    no_mag = w.steps.with_columns(strength_ut=nan, azimuth_deg=nan, polar_deg=nan)
    with pytest.raises(LocalizationError, match="no magnetometer"):
        Localizer(f1_bundle).run(no_mag, start_xy=w.start_xy)
    # methods without magnetic update still run
    make_localizer("pf_no_mag", f1_bundle).run(no_mag, start_xy=w.start_xy)
    # auto picks the filter on this floor's map, which cannot run such a walk; told the walk
    # has no magnetometer it takes the alignment (the command line tells it per walk)
    assert auto_method(f1_bundle.manifest["metrics"]).method == "indoormap"
    with pytest.raises(LocalizationError, match=r"needs the magnetic field \(align, pf_no_mag"):
        make_localizer("auto", f1_bundle).run(no_mag, start_xy=w.start_xy)
    choice = auto_method(f1_bundle.manifest["metrics"], magnetometer=False)
    assert choice.method == "align" and "no magnetometer" in choice.why
    loc = make_localizer("auto", f1_bundle, magnetometer=False)
    assert loc.method == "align" and loc.auto_choice == choice  # kept for the CLI to say why
    track = loc.run(no_mag, start_xy=w.start_xy)
    assert len(track) == len(no_mag)


def test_plot_track_refuses_transposed_waypoints(f1_bundle, sim_walks, tmp_path):  # noqa: F811
    """plot_track reshaped (2, k) waypoints row-major, drawing x and y mixed up."""
    pytest.importorskip("matplotlib")
    from localize.plots import plot_track

    w = _f1(sim_walks)[0]
    track = make_localizer("pdr", f1_bundle).run(w.steps, start_xy=w.start_xy)
    xy = np.array([[10.0, 5.0], [20.0, 5.0], [30.0, 6.0]])
    with pytest.raises(ValueError, match=r"plot_track waypoints_xy: .* got \(2, 3\) "
                                         r"\(transposed\? one row per point\)"):
        plot_track(tmp_path / "t.png", f1_bundle, {"pdr": track}, xy.T)
    assert not (tmp_path / "t.png").exists()
    assert plot_track(tmp_path / "t.png", f1_bundle, {"pdr": track}, xy)
    assert (tmp_path / "t.png").stat().st_size > 1000
    assert plot_track(tmp_path / "none.png", f1_bundle, {"pdr": track}, [])  # no waypoints
    # a notebook takes the figure itself, and draws on it (it only got a file)
    from localize.plots import draw_floor, track_figure

    fig = track_figure(f1_bundle, {"pdr": track}, xy, "a title " * 30)
    ax = fig.axes[0]
    assert [line.get_label() for line in ax.get_lines()][0] == "pdr"
    assert ax.get_title().count("\n") >= 2  # a long title wrapped, not cut at the edge
    assert ax.get_legend().get_bbox_to_anchor().y0 < ax.bbox.y0  # below the map, not on it
    from matplotlib.figure import Figure

    own = Figure().subplots()
    draw_floor(own, f1_bundle)
    assert own.get_aspect() == 1 and len(own.get_images()) == 1


def test_bundle_of_another_floor_or_site(truth_bundles, sim_walks):  # noqa: F811
    f2 = load_bundle(truth_bundles["F2"])
    w = _f1(sim_walks)[0]
    with pytest.raises(LocalizationError, match="floor"):
        Localizer(f2).run(w.steps, start_xy=w.start_xy)
    other_site = replace(w.steps, site_id="another-site")
    with pytest.raises(LocalizationError, match="site"):
        Localizer(load_bundle(truth_bundles["F1"])).run(other_site, start_xy=w.start_xy)


def test_unknown_floor(truth_bundles, sim_walks):  # noqa: F811
    maps = SiteMaps([load_bundle(truth_bundles["F1"]), load_bundle(truth_bundles["F2"])])
    w = _f1(sim_walks)[0]
    assert maps.select(w.steps).floor_id == w.steps.floor_id
    with pytest.raises(LocalizationError, match="unknown floor nope \\(F9\\); bundles exist "
                       "for floors F1, F2$"):
        maps.select(replace(w.steps, floor_id="nope", floor_name="F9"))
    # a single floor's bundle given for a walk of another floor: what to give instead
    with pytest.raises(LocalizationError, match="the bundles given hold only floor F2: give the "
                       "folder of the site's bundles"):
        SiteMaps([load_bundle(truth_bundles["F2"])]).select(w.steps)
    with pytest.raises(LocalizationError, match="site"):
        maps.select(replace(w.steps, site_id="elsewhere"))
    with pytest.raises(LocalizationError, match="no floor"):
        maps.select(replace(w.steps, floor_id="", floor_name=""))


def test_other_bad_calls(f1_bundle, sim_walks):  # noqa: F811
    w = _f1(sim_walks)[0]
    loc = Localizer(f1_bundle)
    with pytest.raises(LocalizationError, match="start"):
        loc.step(w.steps[0])
    with pytest.raises(LocalizationError, match="more than 200 m off the floor's map"):
        loc.start(5000.0, 5000.0)
    with pytest.raises(LocalizationError, match="no start position"):
        loc.run(w.steps)  # neither a start nor a radio model
    with pytest.raises(LocalizationError):
        FilterParams(n_particles=0)
    with pytest.raises(LocalizationError):
        FilterParams(weight_mode="magic")
    with pytest.raises(LocalizationError):
        make_localizer("nope", f1_bundle)
    # a NaN noise passed validation and crashed steps later with an IndexError deep in the
    # resampling; every number is checked, and noise may not be negative
    for bad, match in [(dict(heading_noise_deg=float("nan")), "heading_noise_deg must be a "
                                                             "finite number, got nan"),
                       (dict(step_length_noise_m=-0.1), "step_length_noise_m must be >= 0"),
                       (dict(genome_a_range=(1.0, 0.5)), "genome_a_range must be .* low < high"),
                       (dict(genome_b_range=(0.1,)), "genome_b_range must be 2 finite numbers"),
                       (dict(heading_bias_sd_deg="3"), "heading_bias_sd_deg must be a finite"),
                       (dict(n_particles=True), "n_particles must be a whole number"),
                       (dict(step_length_nominal_m=float("inf")), "must be a finite number"),
                       # a billion particles asked for tens of GB before failing
                       (dict(n_particles=10**9), "n_particles must be at most 1,000,000"),
                       (dict(n_particles_start=2 * 10**6), "n_particles_start must be at most"),
                       # recoveries widen from the one to the other: a smaller maximum
                       # narrowed them instead
                       (dict(recovery_half_width_m=8.0, recovery_max_half_width_m=5.0),
                        r"recovery_max_half_width_m \(5 m\) must be at least "
                        r"recovery_half_width_m \(8 m\)")]:
        with pytest.raises(LocalizationError, match=match):
            FilterParams(**bad)
    with pytest.raises(LocalizationError, match="n_particles must be a whole number"):
        FilterParams(n_particles=2.5)
    # the nested feature parameters: a NaN window crashed run() with a TypeError
    for bad, match in [(dict(window=float("nan")), "FeatureParams.window must be a whole"),
                       (dict(smooth=2.5), "FeatureParams.smooth must be a whole number"),
                       (dict(award=float("inf")), "FeatureParams.award must be a finite")]:
        with pytest.raises(LocalizationError, match=match):
            FeatureParams(**bad)
    # numpy numbers are numbers, a range may be a list or an array, a spread may be
    # unbounded: stored as Python numbers and tuples, so hashable and JSON round-tripping
    p = FilterParams(n_particles=np.int64(50), heading_noise_deg=np.float32(6.0),
                     mode_spread_m=float("inf"), genome_a_range=np.array([0.1, 0.9]),
                     genome_b_range=[-0.5, 0.5],
                     strength=FeatureParams(window=np.int64(4), award=np.float32(50.0)))
    assert p.genome_a_range == (0.1, 0.9) and p.genome_b_range == (-0.5, 0.5)
    assert type(p.n_particles) is int and type(p.strength.window) is int
    assert FilterParams.from_dict(json.loads(p.to_json())) == p and hash(p)


def test_switches_take_only_true_or_false_and_features_take_dicts(f1_bundle):  # noqa: F811
    """Text for a switch, as a YAML, CSV or environment value gives it ("False", "no"), was
    taken as true: ``radio_update="False"`` ran the radio update. A feature given as a dict
    failed with an AttributeError (``from_dict`` alone took one, and built it over
    FeatureParams' defaults, not the feature's: ``{"strength": {"window": 5}}`` lost the
    strength threshold of 0.5 for 0.05). A dict for the parameters of a localizer or an
    engine failed with an AttributeError too."""
    for bad, said in [(dict(radio_update="False"), "radio_update must be True or False, got "
                                                   "'False'"),
                      (dict(turn_correction=2), "turn_correction must be True or False"),
                      (dict(strength={"enabled": "no"}), "FeatureParams.enabled must be True"),
                      (dict(strength=3), "strength must be a FeatureParams or a dict of its "
                                         "fields, got int"),
                      (dict(polar={"windw": 3}), "polar: unknown feature parameter(s) 'windw'")]:
        with pytest.raises(LocalizationError, match=re.escape(said)):
            FilterParams(**bad)
    with pytest.raises(LocalizationError, match="FeatureParams.enabled must be True or False"):
        FeatureParams(enabled="no")
    assert FilterParams(radio_update=np.bool_(False)).radio_update is False
    assert FilterParams(radio_update=0).radio_update is False  # an int() of a config value
    # a feature dict over the papers' parameters changes the papers' feature
    assert FilterParams.paper_params(strength={"window": 5}).strength == FeatureParams(
        window=5, award=70.0, threshold=0.05)
    for p in (FilterParams(strength={"window": 5}),
              FilterParams.from_dict({"strength": {"window": 5}}),
              FilterParams().with_features(strength={"window": 5})):
        assert p.strength == FeatureParams(window=5, threshold=0.5)  # the strength defaults
    with pytest.raises(LocalizationError, match="unknown feature 'bogus'"):
        FilterParams().with_features(bogus={"window": 3})
    with pytest.raises(LocalizationError, match="unknown filter parameter.*'n_particle'"):
        FilterParams.from_dict({"n_particle": 100})
    a = Localizer(f1_bundle, {"n_particles": 100}, rng=0)
    assert a.params == FilterParams(n_particles=100)
    assert MultiUserEngine(f1_bundle, {"n_particles": 100}).params.n_particles == 100
    assert make_localizer("indoormap", f1_bundle, {"n_particles": 100}).params.n_particles == 100
    with pytest.raises(TypeError, match=r"Localizer\(params\): a FilterParams is needed"):
        Localizer(f1_bundle, 100)
    for seed in ("7", 1.5, -1, True):  # numpy's errors did not name the argument
        with pytest.raises(LocalizationError, match="rng must be a seed"):
            Localizer(f1_bundle, rng=seed)
        with pytest.raises(LocalizationError, match="rng must be a seed"):
            MultiUserEngine(f1_bundle, rng=seed)
    for seed in (np.int64(3), np.random.SeedSequence(3), np.random.PCG64(3), [3]):
        assert Localizer(f1_bundle, rng=seed).rng.integers(1 << 30) == \
            np.random.default_rng(3 if not isinstance(seed, list) else [3]).integers(1 << 30)


def test_run_takes_only_true_or_false_to_smooth_and_a_finite_start_time(f1_bundle,  # noqa: F811
                                                                           sim_walks):  # noqa: F811
    """``run(smooth="no")`` smoothed; ``start_t_ms=nan`` gave a track starting at NaN and
    ``inf`` said the first step came before the start."""
    w = _f1(sim_walks)[0]
    for method in ("indoormap", "align"):
        loc = make_localizer(method, f1_bundle, {"n_particles": 50})
        for kw, said in ((dict(smooth="no"), "smooth must be True or False, got 'no'"),
                         (dict(start_t_ms=np.nan), "start_t_ms must be a finite time"),
                         (dict(start_t_ms=np.inf), "start_t_ms must be a finite time"),
                         (dict(start_t_ms="0"), "start_t_ms must be a number")):
            with pytest.raises(LocalizationError, match=re.escape(said)):
                loc.run(w.steps, start_xy=w.start_xy, **kw)
        assert len(loc.run(w.steps, start_xy=w.start_xy, smooth=np.bool_(True))) == len(w.steps)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_the_wrong_thing_passed_names_what_is_needed(f1_bundle, sim_walks, method):  # noqa: F811
    """A path where a bundle or trace belongs, a trace where its steps belong, the whole walk
    to step(): each failed deep inside (an AttributeError at filter.py:93, a TypeError in
    floors.py, numpy's ambiguous truth value) instead of saying what to pass."""
    from survey.step_summaries import ble_scans_of, scans_of, step_summaries, waypoints_of
    from survey.trace_reader import read_trace

    w, *others = _f1(sim_walks)
    scans = [(s, xy) for v in others for s, xy in zip(v.steps.scans, v.true_xy)
             if s is not None]
    radio = KnnRadioPositioner.from_scans(np.array([xy for _, xy in scans]),
                                          [s for s, _ in scans])
    for wrong in (str(w.trace_path.parent), None):
        with pytest.raises(TypeError, match=r"\(bundle\): a MapBundle is needed "
                           r"\(localize.bundle.load_bundle\(path\) opens one.*not "
                           + type(wrong).__name__):
            make_localizer(method, wrong, radio=radio)
    loc = make_localizer(method, f1_bundle, FilterParams(n_particles=100), radio=radio, rng=0)
    trace = read_trace(w.trace_path)
    with pytest.raises(TypeError, match=r"run\(steps\): a StepSummaries is needed "
                       r"\(survey.step_summaries.step_summaries\(trace\).*not Trace"):
        loc.run(trace, start_xy=w.start_xy)
    loc.start(*w.start_xy, t_ms=float(w.steps.t_ms[0]) - 500.0)
    with pytest.raises(TypeError, match=r"step\(s\): a StepSummary is needed \(one element "
                       r"of StepSummaries; run\(\) localizes a whole walk\), not StepSummaries"):
        loc.step(w.steps)
    assert loc.step(w.steps[0]).t_ms == w.steps.t_ms[0]  # the refusals left it usable
    if method == "indoormap":  # the engines of many users too
        from localize.align_engine import MultiUserAligner
        from localize.engine import MultiUserEngine

        for engine in (MultiUserEngine, MultiUserAligner):
            with pytest.raises(TypeError, match=rf"{engine.__name__}\(bundle\): a MapBundle"):
                engine(str(w.trace_path.parent))
    for fn in (step_summaries, scans_of, ble_scans_of, waypoints_of):
        for wrong in (str(w.trace_path), w.steps):
            with pytest.raises(TypeError, match=rf"{fn.__name__}: a Trace is needed "
                               r"\(survey.trace_reader.read_trace\(path\).*not "
                               + type(wrong).__name__):
                fn(wrong)


def test_sampling_at_no_position_gives_nan_quietly(f1_bundle):  # noqa: F811
    """NaN and absurd coordinates (a lost track) sample as NaN, without numpy's 'invalid value
    encountered in cast' warning (turned into an error here)."""
    import warnings

    x0, y0 = f1_bundle.grid.x0_m, f1_bundle.grid.y0_m
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = f1_bundle.sample("strength", [np.nan, x0 + 1.0, 1e300, -np.inf],
                               [y0 + 1.0, np.nan, y0 + 1.0, y0 + 1.0])
    assert got.shape == (4,) and np.isnan(got).all()


@pytest.mark.parametrize("method", ["indoormap", "align"])
def test_bad_starts_and_steps_are_localization_errors(tmp_path, f1_bundle, sim_walks,  # noqa: F811
                                                      method):
    """Each of these used to hang (a start square of width 0 doubled forever), escape as a
    raw ValueError/IndexError/AttributeError, or run on (the aligner placed a walk 900 km
    off, the streaming filter took steps going back in time)."""
    import pyarrow as pa

    from mapping.bundle_writer import BundleContent, write_bundle

    w = _f1(sim_walks)[0]
    loc = make_localizer(method, f1_bundle, rng=0)
    for start, match in [((float("nan"), 3.0), "not finite"), ((1.0,), "not two numbers"),
                         ((1e6, -1e6), "more than 200 m off"), ("ab", "not two numbers")]:
        with pytest.raises(LocalizationError, match=match):
            loc.run(w.steps, start_xy=start)
    if method == "indoormap":
        for half_width in (0.0, -1.0, float("nan")):
            with pytest.raises(LocalizationError, match="half-width"):
                loc.run(w.steps, start_xy=w.start_xy, half_width_m=half_width)
    for streaming in (loc, make_localizer("pdr", f1_bundle)):
        # a start after the first step (a scan's start takes the scan's time): the refusal
        # says what to do
        streaming.start(*w.start_xy, t_ms=float(w.steps.t_ms[1]))
        with pytest.raises(LocalizationError, match=r"comes before the start .* skip the steps "
                                                    r"before it, or start earlier"):
            streaming.step(w.steps[0])
        for t_start in (float("nan"), "soon"):  # every step after it passed, or crashed
            with pytest.raises(LocalizationError, match="start time .* is not a finite"):
                streaming.start(*w.start_xy, t_ms=t_start)
        streaming.start(*w.start_xy, t_ms=float(w.steps.t_ms[0]))
        streaming.step(w.steps[0])  # at the start time: allowed
        for t_ms, match in ((float(w.steps.t_ms[0]) - 1, "comes before the last one"),
                            (float("nan"), "has no time")):
            with pytest.raises(LocalizationError, match=match):
                streaming.step(replace(w.steps[1], t_ms=t_ms))
        # a step sent twice is refused, as run() refuses equal times; it was walked twice
        with pytest.raises(LocalizationError, match="has the last step's time: the same step "
                                                    "sent twice"):
            streaming.step(w.steps[0])
        assert streaming.step(w.steps[1]).t_ms == w.steps.t_ms[1]  # the stream goes on
    write_bundle(tmp_path / "_site", BundleContent("site", "", "", kind="site",
                                                   tables={"t": pa.table({"a": [1]})}))
    with pytest.raises(LocalizationError, match="site-level bundle"):
        make_localizer(method, load_bundle(tmp_path / "_site"))


def test_a_glitch_in_the_accelerometer_does_not_throw_the_aligned_track(f1_bundle,  # noqa: F811
                                                                        sim_walks):
    """One step's acceleration swing of 1e30 (a corrupt sample) made a Weinberg step of
    thousands of km; the aligner cuts a step at MAX_STEP_M."""
    from localize.align import walk_shape
    from localize.params import MAX_STEP_M

    w = _f1(sim_walks)[0]
    swing = np.array(w.steps.delta_acc_ms2, dtype=float)
    swing[5] = 1e30
    shape = walk_shape(replace(w.steps, delta_acc_ms2=swing))
    assert np.abs(np.diff(shape)).max() <= MAX_STEP_M + 1e-9
    track = make_localizer("align", f1_bundle).run(replace(w.steps, delta_acc_ms2=swing),
                                                   start_xy=w.start_xy, smooth=True)
    g = f1_bundle.grid
    assert (track.x_m <= g.x0_m + g.width * g.cell_m + 10).all()


def test_a_bad_tick_moves_no_user(f1_bundle, sim_walks):  # noqa: F811
    """One user's NaN compass, inputs of the wrong length or a user twice used to raise a raw
    IndexError/ValueError (or advance a twice-named user once) after some users had moved;
    now the tick is refused before anything moves, and the next good tick works."""
    walks = _f1(sim_walks)[:3]
    eng = MultiUserEngine(f1_bundle, FilterParams(n_particles_start=0), rng=4)
    ids = eng.add_users(np.array([v.start_xy for v in walks]))
    cols = ["compass_deg", "frequency_hz", "turn_deg", "strength_ut", "azimuth_deg",
            "polar_deg", "attitude"]

    def inputs(i, **change):
        values = {c: np.array([getattr(v.steps, c)[i] for v in walks]) for c in cols}
        return StepInputs(**{**values, **change})

    before = eng.state.x.copy()
    compass = inputs(0).compass_deg.copy()
    compass[1] = np.nan
    for call, match in [(lambda: eng.tick(None, inputs(0, compass_deg=compass)),
                         rf"users \[{ids[1]}\]: no compass heading"),
                        (lambda: eng.tick(ids, inputs(0, turn_deg=np.zeros(2))),
                         r"turn_deg has shape \(2,\)"),
                        (lambda: eng.tick([ids[0], ids[0]], inputs(0)),
                         "appears twice"),
                        (lambda: eng.tick(ids + 0.7, inputs(0)),  # 1.7 was taken as user 1
                         r"user ids must be whole numbers .*, got \[0.7, 1.7, 2.7\]"),
                        (lambda: eng.tick(["a", "b", "c"], inputs(0)),
                         "user ids must be whole numbers"),
                        (lambda: eng.add_users([10.0, 5.0, 3.0]),
                         r"start_xy has shape \(3,\), expected \(k, 2\)"),
                        (lambda: eng.add_users("10,5"), "start_xy is not numeric"),
                        (lambda: eng.add_users(["10", "5"]), "start_xy is not numeric"),
                        (lambda: eng.add_users([True, False]), "start_xy is not numeric"),
                        (lambda: eng.tick([1e19, 0, 1], inputs(0)),
                         "user ids must be whole numbers"),
                        (lambda: eng.tick([ids[0], 99], StepInputs(
                            **{c: getattr(inputs(0), c)[:2] for c in cols})),
                         r"unknown user ids in tick: \[99\]"),
                        (lambda: eng.tick(None, inputs(0, frequency_hz=np.array(
                            ["1.8", "x", "1.8"]))), "frequency_hz is not numeric"),
                        (lambda: eng.tick(None, inputs(0), fix_xy_m=[
                            [np.nan, np.nan], [1e6, 1e6], [np.nan, np.nan]]),
                         rf"users \[{ids[1]}\]: fix_xy_m .* within 200 m")]:
        with pytest.raises(LocalizationError, match=match):
            call()
        np.testing.assert_array_equal(eng.state.x, before)
    assert eng.n_users == 3
    out = eng.tick(ids.astype(float), inputs(0))  # whole numbers as floats are ids
    assert np.isfinite(out.x_m).all() and len(out.x_m) == 3
    one = {c: getattr(walks[0].steps, c)[1] for c in cols}  # one user: scalars still work
    assert len(eng.tick([ids[0]], StepInputs(**one)).x_m) == 1


def test_step_errors_needs_one_true_position_per_step():
    from localize.track import Estimate, Track

    z = np.zeros(3)
    track = Track(z, np.array([0.0, 1.0, 2.0]), z, z, np.ones(3), np.zeros(3, bool),
                  Estimate(0.0, 0.0, 0.0))
    np.testing.assert_allclose(step_errors(track, [[0, 0], [1, 1], [2, 0]]), [0, 1, 0])
    with pytest.raises(ValueError, match=r"step_errors: positions of shape \(3, 2\) expected, "
                                         r"one row per point, got \(1, 2\)"):
        step_errors(track, [[0.0, 0.0]])  # before: broadcast against every step
    # waypoints given as (2, k), x and y mixed up by a row-major reshape before
    timed = Track(np.array([0.0, 1.0, 2.0]), np.array([0.0, 1.0, 2.0]), z, z, np.ones(3),
                  np.zeros(3, bool), Estimate(-1.0, 0.0, 0.0))
    t_wp, xy_wp = [0.0, 1.0, 2.0], np.array([[0.0, 1.0, 2.0], [0.0, 1.0, 0.0]])
    with pytest.raises(ValueError, match=r"got \(2, 3\) \(transposed\? one row per point\)"):
        waypoint_errors(timed, t_wp, xy_wp)
    np.testing.assert_allclose(waypoint_errors(timed, t_wp, xy_wp.T), [0, 1, 0])
    assert waypoint_errors(timed, [], np.empty(0)).shape == (0,)
    # one waypoint as a flat (x, y), with its time a scalar: it was refused as shape (2,)
    np.testing.assert_allclose(waypoint_errors(timed, 1.0, (1.0, 3.0)), [3.0])
    with pytest.raises(ValueError, match=r"shape \(2, 2\) expected"):
        waypoint_errors(timed, [0.0, 1.0], (1.0, 3.0))  # two times, one point: ambiguous
    # times of any shape keep it, with (x, y) last (a (2, 3) grid gave (2, 6): x, then y)
    grid = np.array([[0.0, 0.5, 1.0], [1.5, 2.0, 9.0]])
    xy = timed.at(grid)
    assert xy.shape == (2, 3, 2)
    np.testing.assert_allclose(xy.reshape(-1, 2), timed.at(grid.ravel()))
    assert timed.at(0.5).shape == (1, 2) and timed.at([0.5]).shape == (1, 2)
    # times in seconds, or another walk's: every waypoint was scored at the track's end
    walk = Track(1.7e12 + np.array([0.0, 1e3, 2e3]), np.array([0.0, 1.0, 2.0]), z, z,
                 np.ones(3), np.zeros(3, bool), Estimate(1.7e12 - 500, 0.0, 0.0))
    for t_wp in ((1.7e12 + np.array([0, 2e3])) / 1000, 1.7e12 + 3.6e6 + np.array([0, 2e3])):
        with pytest.raises(ValueError, match="lies within 60 s of the track's 1699999999500 "
                                             "to 1700000002000 .* in seconds, or another "):
            waypoint_errors(walk, t_wp, [[0.0, 0.0], [2.0, 0.0]])
    # standing still a while before the first step or after the last: scored at its ends
    np.testing.assert_allclose(
        waypoint_errors(walk, 1.7e12 + np.array([-50e3, 1e3, 59e3]), [[0, 0], [1, 0], [2, 0]]),
        [0, 0, 0])


def test_engine_radio_fixes_bring_wrongly_started_users_back(f1_bundle, sim_walks):  # noqa: F811
    """Session 29: the multi-user engine had no radio input, so a server could only start its
    users where it was told and never correct them. Users started 10 m off their true start
    (a wrong Wi-Fi fix) now come back with unbiased 3 m fixes every fourth step (the
    Gaussian update and the re-seeding around far fixes, as the single-user filter with a
    radio model that only locates); without fixes they stay lost. A tick whose fixes are all
    NaN is the tick without fixes, to the bit."""
    walks = _f1(sim_walks)
    n = min(len(v.steps) for v in walks)
    cols = ["compass_deg", "frequency_hz", "turn_deg", "strength_ut", "azimuth_deg",
            "polar_deg", "attitude"]
    rng = np.random.default_rng(5)
    angle = rng.uniform(0, 2 * np.pi, len(walks))
    starts = np.array([v.true_xy[0] for v in walks]) + 10.0 * np.column_stack(
        [np.cos(angle), np.sin(angle)])
    true = np.stack([v.true_xy[:n] for v in walks])  # (users, steps, 2)
    noisy = true + rng.normal(0.0, 3.0, true.shape)

    def run(with_fixes: bool, nan_fixes: bool = False) -> np.ndarray:
        p = FilterParams(n_particles_start=0, init_half_width_m=3.0)
        eng = MultiUserEngine(f1_bundle, p, rng=3)
        ids = eng.add_users(starts)
        est = []
        for i in range(n):
            inp = StepInputs(*(np.array([getattr(v.steps, c)[i] for v in walks]) for c in cols))
            if with_fixes and i % 4 == 0:
                out = eng.tick(ids, inp, noisy[:, i], np.full(len(walks), 3.0))
            elif nan_fixes:
                out = eng.tick(ids, inp, np.full((len(walks), 2), np.nan))
            else:
                out = eng.tick(ids, inp)
            est.append(np.column_stack([out.x_m, out.y_m]))
        err = np.hypot(*(np.stack(est, axis=1) - true).transpose(2, 0, 1))
        return err[:, n // 2:]  # the second half of every walk

    lost, found = run(False), run(True)
    assert (np.median(found, axis=1) < 1.5).all()  # 0.3-0.5 m
    assert (np.median(lost, axis=1) > 5.0).sum() >= 4  # 5 of 6 stay 8-12 m off
    np.testing.assert_array_equal(run(False, nan_fixes=True), lost)
    eng = MultiUserEngine(f1_bundle, FilterParams(n_particles_start=0), rng=3)
    ids = eng.add_users(starts[:2])
    before = eng.state.x.copy()
    inp = StepInputs(*(np.array([getattr(v.steps, c)[0] for v in walks[:2]]) for c in cols))
    for call, match in [(lambda: eng.tick(ids, inp, np.zeros((3, 2))),
                         r"fix_xy_m has shape \(3, 2\), expected \(2, 2\)"),
                        (lambda: eng.tick(ids, inp, np.zeros((2, 2)), np.ones(3)),
                         "fix_sigma_m has 3 values, expected 2")]:
        with pytest.raises(LocalizationError, match=match):
            call()
        np.testing.assert_array_equal(eng.state.x, before)
