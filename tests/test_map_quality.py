"""The build's measure of its magnetic map (held-out strength) and the localizer method chosen
by it (``--method auto``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner
from localize_fixtures import f1_bundle, sim_walks, truth_bundles  # noqa: F401  (fixtures)
from radio_fixtures import SITE, built  # noqa: F401  (fixture)
from test_localize_align import _BiasedRadio, _f1_with_scans

from localize.align import WalkAligner
from localize.baselines import make_localizer
from localize.bundle import Grid, MapBundle, load_bundle
from localize.filter import Localizer
from localize.methods import AUTO_MIN_CORR_5M, METHODS, SMOOTHABLE, auto_method
from localize.params import FilterParams
from mapping.holdout import choose_smoothing, heldout_quality
from mapping.interpolate import RasterParams
from survey.cli import main

GRID = Grid(0.0, 0.0, 0.25, 160, 40)  # 40 x 10 m
MASK = np.ones(GRID.shape, dtype=bool)


def _walks(rng, field, n_walks=8):
    """Walks along x at y = 2-8 m, each walk's samples in order; ``field(x, y, k)`` (uT)."""
    x, y, v, walk = [], [], [], []
    for k in range(n_walks):
        xs = np.arange(1.0, 39.0, 0.1)
        ys = 2.0 + 6.0 * k / (n_walks - 1) + 0.1 * rng.standard_normal(len(xs))
        x.append(xs)
        y.append(ys)
        v.append(field(xs, ys, k))
        walk.append(np.full(len(xs), k))
    return (np.concatenate(x), np.concatenate(y), np.concatenate(v),
            np.concatenate(walk))


def test_held_out_quality_tells_a_map_that_predicts_from_one_that_does_not():
    """A field the walks share is predicted for walks left out (high skill, field changes
    over 5 m correlated); fields each walk sees alone (what another walk measured there does
    not repeat) are not: skill about 0 and the 5 m correlation near 0."""
    rng = np.random.default_rng(3)
    params = RasterParams(method="local_linear", bandwidth_m=1.0, prior_walks=0.5)

    def shared(x, y, k):
        return 45.0 + 6.0 * np.sin(x / 1.5) + 2.0 * np.cos(y) + 0.5 * rng.standard_normal(len(x))

    phases = rng.uniform(0, 2 * np.pi, 8)

    def own(x, y, k):
        return 45.0 + 6.0 * np.sin(x / 1.5 + phases[k]) + 0.5 * rng.standard_normal(len(x))

    good = heldout_quality(GRID, MASK, *_walks(rng, shared), params)
    bad = heldout_quality(GRID, MASK, *_walks(rng, own), params)
    assert good["skill"] > 0.7 and good["corr_5m"] > 0.9 and good["corr_0.7m"] > 0.5
    assert bad["skill"] < 0.2 and abs(bad["corr_5m"]) < 0.3
    assert good["n_walks"] == 8 and good["folds"] == 5
    assert good["constant_shape_rmse_ut"] > 3.0 > good["shape_rmse_ut"]
    assert heldout_quality(GRID, MASK, *_walks(rng, shared, n_walks=2), params) == {}
    assert heldout_quality(GRID, MASK, *_walks(rng, shared), RasterParams(method="linear")) \
        == {}


def test_held_out_shape_rmse_is_the_cross_validations_score_of_the_chosen_map():
    """Same folds, same residuals: the quality the build records is the score that chose
    the map."""
    rng = np.random.default_rng(4)
    x, y, v, walk = _walks(rng, lambda x, y, k: 45.0 + 4.0 * np.sin(x / 2.0)
                           + 0.3 * rng.standard_normal(len(x)))
    chosen, scores = choose_smoothing(GRID, MASK, x, y, v, walk, RasterParams(method="kernel"),
                                      candidates=(0.5, 1.0, 2.0), subsample=1)
    got = heldout_quality(GRID, MASK, x, y, v, walk, chosen)
    assert got["shape_rmse_ut"] == pytest.approx(min(scores.values()), rel=1e-9)


def test_auto_method_follows_the_recorded_map_quality():
    def metrics(corr):
        return {"heldout_strength": {"corr_5m": corr, "skill": 0.2}}

    low = auto_method(metrics(0.3))
    assert (low.method, low.guided, low.label) == ("align", False, "align")
    assert low.why == "the magnetic map's held-out 5 m change correlation 0.30 < 0.5"
    for good in (AUTO_MIN_CORR_5M, 0.86):
        assert auto_method(metrics(good))[:2] == ("indoormap", True)
    assert auto_method(metrics(0.86)).label == "indoormap guided by align"
    for unmeasured in ({}, {"heldout_strength": None}, {"heldout_strength": {}}):
        assert auto_method(unmeasured) == ("indoormap", False,
                                           "the bundle records no held-out map quality")
    for short in (metrics(None), metrics(math.nan)):  # no held-out walk spans 5 m
        assert auto_method(short) == ("indoormap", False,
                                      "none of the bundle's held-out walks spans 5 m")
    assert "auto" in METHODS and "auto" in SMOOTHABLE


def test_auto_builds_the_chosen_localizer(f1_bundle):  # noqa: F811
    def with_corr(corr):
        manifest = {**f1_bundle.manifest, "metrics": {"heldout_strength": {"corr_5m": corr}}}
        return MapBundle(f1_bundle.path, manifest, f1_bundle.grid, f1_bundle.mask,
                         f1_bundle.layers, f1_bundle.std)

    assert "heldout_strength" not in f1_bundle.manifest.get("metrics", {})  # truth map
    plain = make_localizer("auto", f1_bundle, FilterParams(n_particles=50))
    assert type(plain) is Localizer and plain.params.radio_guide == "fixes"
    guided = make_localizer("auto", with_corr(0.8), FilterParams(n_particles=50), radio=object())
    assert type(guided) is Localizer and guided.params.radio_guide == "align"
    assert guided.params.n_particles == 50 and type(guided.guide) is WalkAligner
    loc = make_localizer("auto", with_corr(0.3))
    assert type(loc) is WalkAligner and loc.method == "align"
    assert loc.auto_choice.method == "align" and "0.30 < 0.5" in loc.auto_choice.why
    assert make_localizer("align", f1_bundle).auto_choice is None  # chosen by the caller
    asked = FilterParams(radio_guide="align")  # the choice decides, whatever was asked
    assert make_localizer("auto", f1_bundle, asked, radio=object()).guide is None


def test_auto_guides_the_filter_only_from_a_radio_fix(f1_bundle, sim_walks):  # noqa: F811
    """On a good map `auto` runs the guided filter: from the walk's first fix its track is
    not the plain filter's; from a given start it is (the guide would hold the start)."""
    manifest = {**f1_bundle.manifest, "metrics": {"heldout_strength": {"corr_5m": 0.8}}}
    good = MapBundle(f1_bundle.path, manifest, f1_bundle.grid, f1_bundle.mask,
                     f1_bundle.layers, f1_bundle.std)
    w = _f1_with_scans(sim_walks)[0]
    for start, guided in ((None, True), (tuple(w.true_xy[0]), False)):
        tracks = []
        for method in ("auto", "indoormap"):
            loc = make_localizer(method, good, FilterParams(n_particles=100),
                                 radio=_BiasedRadio(w, 90), rng=0)
            tracks.append(loc.run(w.steps, start_xy=start))
            assert loc.guided is (guided and method == "auto")
        same = np.array_equal(tracks[0].x_m, tracks[1].x_m)
        assert same is not guided


def test_the_build_records_its_maps_quality_and_localize_says_what_auto_chose(
        built, tmp_path):  # noqa: F811
    """The sample site's floors (6 walks each) carry their held-out strength scores; its
    simulated field repeats across walks, so ``auto`` runs the particle filter there, guided
    by the alignment."""
    for floor in ("F1", "F2"):
        q = load_bundle(built / floor).manifest["metrics"]["heldout_strength"]
        assert q["n_walks"] == 6 and q["folds"] == 5
        assert 0.0 < q["skill"] < 1.0 and AUTO_MIN_CORR_5M < q["corr_5m"] <= 1.0
        assert q["shape_rmse_ut"] < q["constant_shape_rmse_ut"]
    info = CliRunner().invoke(main, ["bundle", "info", str(built / "F1")])
    assert info.exit_code == 0, info.output
    assert "strength on walks the map did not see (5 folds of 6 walks): skill 0." in info.output
    assert "5 m 0." in info.output and "localize --method auto runs indoormap guided by align" in info.output
    walk = next((SITE / "F1" / "path_data_files").iterdir())
    res = CliRunner().invoke(main, ["localize", str(built), str(walk), "-o",
                                    str(tmp_path / "out"), "--no-plot"])
    assert res.exit_code == 0, res.output
    assert "by auto: indoormap guided by align, as the magnetic map's held-out 5 m change " \
        "correlation 0." in res.output
    res = CliRunner().invoke(main, ["localize", str(built), str(walk), "-o",
                                    str(tmp_path / "out"), "--no-plot", "--overwrite",
                                    "--start", "waypoint"])
    assert res.exit_code == 0, res.output
    assert "by auto: indoormap, as the magnetic map's held-out" in res.output
    assert "(not guided: a given start)" in res.output
