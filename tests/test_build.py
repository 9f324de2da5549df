"""Building floor bundles from a survey store: layers, determinism, accuracy on simulated truth."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import shapely
import shapely.affinity
import shapely.geometry
from click.testing import CliRunner

from localize.bundle import load_bundle
from mapping.build import BuildError, BuildParams, build_floor
from mapping.bundle_report import bundle_differences
from mapping.grid import distance_to_reachable_m
from mapping.cli_build import THIN_COVERAGE
from mapping.bundle_writer import write_bundle
from mapping.errors import FingerprintError
from mapping.floorplan import FloorPlan, FloorPlanError, read_floor_plan
from mapping.radio_build import build_site_radio
from mapping.truth_errors import truth_errors
from survey.cli import main
from survey.errors import BundleError
from survey.ingest import ingest
from survey.process_store import process_store
from survey.sim.site import load_field
from survey.store import SurveyStore

SITE = Path(__file__).resolve().parents[1] / "data" / "sample_site"


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("store") / "store"
    ingest([SITE / "F1" / "path_data_files", SITE / "F2" / "path_data_files"], path)
    process_store(path)
    return path


def test_layers_and_manifest(store, tmp_path):
    content = build_floor(store, read_floor_plan(SITE / "F1"), floor="F1")
    assert set(content.layers) == {"strength", "horizontal", "vertical", "azimuth", "polar",
                                   "heading_offset"}
    write_bundle(tmp_path / "b", content)
    b = load_bundle(tmp_path / "b")
    m = b.manifest
    assert m["floor_name"] == "F1" and len(m["build"]["source_walks"]) == 6
    assert all(len(w["sha256"]) == 64 for w in m["build"]["source_walks"])
    assert b.layer_unit("strength") == "uT" and m["layers"]["azimuth"]["kind"] == "angle"
    assert 0.5 < m["metrics"]["coverage"]["within_2m"] <= 1.0
    assert m["metrics"]["samples_on_plan"] == 1.0  # the whole floor's plan: every sample on it
    assert m["metrics"]["bandwidth_m"] in (0.5, 0.75, 1.0, 1.5)  # accurate survey: sharp map
    s = b.layers["strength"]
    assert np.isnan(s[~b.mask]).all() and np.nanmin(s) > 20 and np.nanmax(s) < 80
    assert b.table("source_walks").num_rows == 6 and b.table("levelling").num_rows >= 1


def test_map_against_simulated_truth(store):
    """Strength on surveyed cells within a few sensor-noise levels of the true field, and the
    heading-offset layer within 3 deg (median) of minus the simulated compass deviation. The
    sample has 6 walks a floor; benchmarks/map_truth.py reports the 48-walk site."""
    truth = json.loads((SITE / "truth" / "site.json").read_text())
    content = build_floor(store, read_floor_plan(SITE / "F1"), floor="F1")
    field = load_field(truth, "F1")
    true_xy = pd.concat([pd.read_parquet(SITE / w["truth_path"])[["x_m", "y_m"]]
                         for w in truth["walks"] if w["floor"] == "F1"]).to_numpy()
    errors = truth_errors(content.grid, content.layers, field, true_xy)
    assert len(errors.strength_ut) > 300
    assert np.sqrt(np.mean(errors.strength_ut ** 2)) < 3.0  # sensor noise 0.7 uT (6 walks)
    assert np.median(np.abs(errors.heading_offset_deg)) < 3.0
    # looked up at the walked positions themselves: almost every one has a value there
    assert len(errors.strength_walked_ut) > 0.95 * len(true_xy)
    assert np.sqrt(np.mean(errors.strength_walked_ut ** 2)) < 2.5  # 2.0 here


def test_walk_by_walk_layers_equal_the_in_memory_rasters(store):
    """The build reads walk by walk (mapping.field_layers); its layers and levelling must be
    those of the whole floor's samples in one table, bit for bit."""
    from dataclasses import replace

    from mapping.build import build_smoothing, floor_samples
    from mapping.field_layers import FIELD_LAYERS, field_layer_values
    from mapping.interpolate import raster
    from mapping.levelling import apply_session_residuals, fit_session_residuals

    plan = read_floor_plan(SITE / "F1")
    params = BuildParams(radio=None, auto_bandwidth=False)
    content = build_floor(store, plan, floor="F1", params=params)
    samples = floor_samples(SurveyStore.open(store), None, "F1")
    residuals = fit_session_residuals(samples, params.levelling)
    assert residuals["n_pairs"].sum() > 0  # the levelling is exercised
    values = field_layer_values(apply_session_residuals(samples, residuals))
    for name, (_, kind, _) in FIELD_LAYERS.items():
        expect = raster(content.grid, content.mask, samples["x_m"].to_numpy(),
                        samples["y_m"].to_numpy(), values[name], samples["trace_id"],
                        params.raster, angle=kind == "angle")
        np.testing.assert_array_equal(content.layers[name].values, expect[0], err_msg=name)
        np.testing.assert_array_equal(content.layers[name].std, expect[1], err_msg=name)
    assert content.metrics["n_samples"] == len(samples)
    # the means come in trace-id order whatever order the walks are read in
    from mapping.build import floor_walks
    from mapping.field_layers import reduce_field

    st = SurveyStore.open(store)
    walks = floor_walks(st, None, "F1")
    forward = reduce_field(st, walks, content.grid, residuals)
    backward = reduce_field(st, walks.iloc[::-1], content.grid, residuals)
    for name, (cell, mean) in forward.walk_means.items():
        np.testing.assert_array_equal(backward.walk_means[name][0], cell)
        np.testing.assert_array_equal(backward.walk_means[name][1], mean)
    assert np.array_equal(np.unique(backward.cv_walk), np.arange(len(walks)))
    # the smoothing the build picks equals the in-memory choice
    same_cells = replace(params, auto_bandwidth=True, min_cell_m=params.cell_m)
    auto = build_floor(store, plan, floor="F1", params=same_cells)
    chosen, scores = build_smoothing(samples, apply_session_residuals(samples, residuals),
                                     content.grid, content.mask, params)
    assert auto.metrics["bandwidth_m"] == chosen.bandwidth_m
    assert auto.metrics["prior_walks"] == chosen.prior_walks
    assert auto.metrics["smoothing_cv_shape_rmse_ut"] == scores
    assert auto.metrics["slope_ridge"] == chosen.slope_ridge
    assert auto.metrics["interpolator"] == chosen.method
    if chosen.method == "local_quadratic":
        assert auto.metrics["curvature_ridge"] == chosen.curvature_ridge
    assert len(scores) == 8 * 4 * 4 * 5  # bandwidths x shrinkages x slope x curvature ridges
    # a kernel at most two cells wide is rastered (and chosen again) on cells of half its width
    assert chosen.bandwidth_m <= 2 * params.cell_m  # the simulated walks are well positioned
    fine = build_floor(store, plan, floor="F1", params=replace(params, auto_bandwidth=True))
    assert fine.grid.cell_m == params.min_cell_m
    assert fine.metrics["bandwidth_m"] <= 2 * chosen.bandwidth_m
    ratio = (params.cell_m / fine.grid.cell_m) ** 2
    assert 0.8 * ratio < fine.mask.sum() / content.mask.sum() < 1.25 * ratio


def test_excluded_walks_stay_out_of_the_map(store):
    plan = read_floor_plan(SITE / "F1")
    full = build_floor(store, plan, floor="F1")
    walks = [w["trace_id"] for w in full.build["source_walks"]]
    held = set(walks[:2])
    part = build_floor(store, plan, floor="F1", exclude_walks=held)
    assert [w["trace_id"] for w in part.build["source_walks"]] == walks[2:]
    assert part.metrics["n_samples"] < full.metrics["n_samples"]
    assert not np.array_equal(part.layers["strength"].values, full.layers["strength"].values,
                              equal_nan=True)
    # the radio maps leave them out too
    assert 0 < part.tables["wifi_rp"].num_rows < full.tables["wifi_rp"].num_rows
    with pytest.raises(BuildError, match="every processed walk of floor .F1. is excluded"):
        build_floor(store, plan, floor="F1", exclude_walks=set(walks))
    with pytest.raises(TypeError, match="collection of trace ids"):
        build_floor(store, plan, floor="F1", exclude_walks=walks[0])
    # an id the store lacks (a typo, a file name) would leave its walk in an "unseen" map
    with pytest.raises(BuildError, match=r"names 1 trace id\(s\) the store does not hold: "
                                         rf"{walks[0]}\.txt\.gz \(trace ids, not file names\)"):
        build_floor(store, plan, floor="F1", exclude_walks=[walks[1], f"{walks[0]}.txt.gz"])


def test_walks_without_a_calibrated_magnetometer_stay_out_of_the_magnetic_layers(tmp_path):
    """Two F1 walks logging only an uncalibrated magnetometer whose bias is 0, 0, 0 (a phone
    that estimates no hard iron, a log converted from raw values): the zero bias was taken
    for the phone's estimate, the walks for calibrated, and the map was 45 uT off. They are
    now not calibrated (a flat phone's own fit is ill-conditioned), and the magnetic layers
    are those of the other walks, as if the two were excluded; their radio rows are used."""
    from survey.process_store import processed_catalog
    from survey.trace_reader import read_trace
    from survey.trace_writer import write_trace

    traces = sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))
    for i, path in enumerate(traces):
        trace = read_trace(path)
        if i < 2:
            sensors = trace.sensors[trace.sensors["stream"] != "magnetic_field"].copy()
            sensors.loc[sensors["stream"] == "magnetic_field_uncalibrated",
                        ["bx", "by", "bz"]] = 0.0
            trace = dataclasses.replace(trace, sensors=sensors.reset_index(drop=True))
        write_trace(tmp_path / "in" / path.name, trace)
    ingest([tmp_path / "in"], tmp_path / "store")
    process_store(tmp_path / "store")
    cat = processed_catalog(tmp_path / "store").sort_values("trace_id")
    raw = [t for t, d in zip(cat["trace_id"], cat["summary"]) if d["calibration"] ==
           "not-calibrated"]
    assert len(raw) == 2 and all(s.endswith("|no-bias") for s in
                                 cat.loc[cat["trace_id"].isin(raw), "session"])
    plan = read_floor_plan(SITE / "F1")
    params = BuildParams(radio=None)
    built = build_floor(tmp_path / "store", plan, floor="F1", params=params)
    without = build_floor(tmp_path / "store", plan, floor="F1", params=params,
                          exclude_walks=raw)
    assert built.metrics["not_calibrated_walks"] == {"trace_ids": sorted(raw),
                                                     "in_magnetic_layers": False}
    for name in ("strength", "vertical", "azimuth"):
        assert np.array_equal(built.layers[name].values, without.layers[name].values,
                              equal_nan=True)
    assert built.metrics["n_walks"] == 6  # every walk is a source (its steps, its radio)
    assert "not_calibrated_walks" not in without.metrics  # calibrated surveys: as before
    # the validation report scores the map the build made, and does not fail it for walks
    # whose field it left out
    from mapping.validate import load_floor_data, validate_bundle

    write_bundle(tmp_path / "bundle", built)
    bundle = load_bundle(tmp_path / "bundle")
    samples = load_floor_data(tmp_path / "store", bundle).samples
    assert set(samples["trace_id"]) == set(cat["trace_id"]) - set(raw)
    report = validate_bundle(bundle, tmp_path / "store")
    said = [f for f in report.findings if f.check == "not_calibrated"]
    assert len(said) == 2 and {f.severity for f in said} == {"info"}
    assert all("left out of the magnetic layers" in f.message for f in said)
    res = CliRunner().invoke(main, ["build", str(tmp_path / "in"), "--plan",
                                    str(SITE / "F1" / "geojson_map.json"), "-o",
                                    str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert re.search(r"warning: F1: 2 walk\(s\) left out of the magnetic layers, their "
                     r"magnetometer not calibrated \(\w+, \w+; `indoormap survey-report", res.output)


def test_release_free_memory_runs_twice():
    from survey.memory import release_free_memory

    release_free_memory()
    release_free_memory()


def test_unknown_floor_is_a_clear_error(store):
    with pytest.raises(BuildError, match=r"no processed walks for floor 'F9'; the store has "
                       r"processed walks of site \S+ floors F1 \(\d+\), F2 \(\d+\)"):
        build_floor(store, read_floor_plan(SITE / "F1"), floor="F9")


def _cropped(plan: FloorPlan, share: float) -> FloorPlan:
    """``plan`` with its outline cut to the western ``share`` of its reachable area's width."""
    x0, y0, x1, y1 = plan.reachable.bounds
    return dataclasses.replace(plan, outline=plan.outline.intersection(
        shapely.box(x0, y0, x0 + share * (x1 - x0), y1)))


def test_a_plan_beside_the_walks_is_a_clear_error(store):
    """A plan that does not cover the walks (another frame) used to end in 'the manifest cannot
    be written' (infinite cross-validation scores) naming a temporary folder. A plan that
    covers a part of them (a wing's plan, 17 % of the samples) built, with good held-out
    figures from the sliver inside, and its maps put a walk 97 m off (a review, session 43)."""
    plan = FloorPlan(shapely.box(100, 100, 140, 125), shapely.Polygon(), 140.0, 125.0)
    with pytest.raises(BuildError, match="none of the .* samples of its 6 walks lie within 2 m "
                                         "of the plan's reachable area"):
        build_floor(store, plan, floor="F1")
    with pytest.raises(BuildError, match=r"only 17 % of the .* samples of its 6 walks lie "
                                         r"within 2 m of the plan's reachable area \(is the "
                                         "plan this floor's, whole, and in the walks' frame"):
        build_floor(store, _cropped(read_floor_plan(SITE / "F1"), 0.3), floor="F1")


def test_a_plan_covering_most_of_the_walks_builds_with_a_warning(tmp_path):
    """Most of the samples on the plan (79 %): built, and the build says how many lie off it."""
    _dxf_of(_cropped(read_floor_plan(SITE / "F1"), 0.8), tmp_path / "F1.dxf")
    res = CliRunner().invoke(main, ["build", str(SITE / "F1" / "path_data_files"), "--plan",
                                    str(tmp_path / "F1.dxf"), "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    on_plan = load_bundle(tmp_path / "out" / "F1").manifest["metrics"]["samples_on_plan"]
    assert 0.7 < on_plan < 0.9  # built (above 0.5), warned (below 0.9)
    assert (f"warning: F1: {100 * (1 - on_plan):.0f} % of the surveyed samples lie more than "
            "2 m outside the plan's reachable area" in res.output)
    # fingerprints where the plan says nobody can stand are left out, and counted
    bundle = load_bundle(tmp_path / "out" / "F1")
    for kind in ("wifi", "ble"):
        rp = bundle.table(f"{kind}_rp")
        off = distance_to_reachable_m(bundle.grid, bundle.mask, rp["x_m"].to_numpy(),
                                      rp["y_m"].to_numpy())
        left_out = bundle.manifest["metrics"]["radio"][kind]["off_plan_reference_points"]
        assert (off <= 2.0).all() and 0.05 < left_out / (left_out + len(rp)) < 0.4


def test_a_build_with_no_readable_walk_says_so(tmp_path):
    floor = tmp_path / "F2"
    shutil.copytree(SITE / "F2", floor, ignore=shutil.ignore_patterns("path_data_files"))
    (floor / "path_data_files").mkdir()
    (floor / "path_data_files" / "walk.txt").write_bytes(b"\x00\xff garbage\n" * 10)
    res = CliRunner().invoke(main, ["build", str(floor), "-o", str(tmp_path / "out")])
    assert res.exit_code == 1 and "no readable walk to build from (1 unreadable)" in res.output
    assert "not processed yet" not in res.output and not (tmp_path / "out").exists()


def test_build_cli_twice_identical_bytes(tmp_path):
    runner = CliRunner()
    for out in ("a", "b"):
        res = runner.invoke(main, ["build", str(SITE / "F2"), "-o", str(tmp_path / out)])
        assert res.exit_code == 0, res.output
        # progress of the long steps reaches a log (CliRunner's streams are no terminal)
        assert "ingest: 6/6 files" in res.output and "process: 6/6 walks" in res.output
    a, b = tmp_path / "a" / "F2", tmp_path / "b" / "F2"
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files and all((a / f).read_bytes() == (b / f).read_bytes() for f in files)
    again = runner.invoke(main, ["build", str(SITE / "F2"), "-o", str(tmp_path / "a")])
    assert again.exit_code == 1 and "exists; pass --overwrite" in again.output
    (tmp_path / "c" / "F2").mkdir(parents=True)  # not a bundle: --overwrite leaves it alone
    (tmp_path / "c" / "F2" / "notes.txt").write_text("keep me")
    other = runner.invoke(main, ["build", str(SITE / "F2"), "-o", str(tmp_path / "c"),
                                 "--overwrite"])
    assert other.exit_code == 1 and "is not a map bundle" in other.output
    assert (tmp_path / "c" / "F2" / "notes.txt").read_text() == "keep me"
    info = runner.invoke(main, ["bundle", "info", str(a)])
    assert info.exit_code == 0 and "layer strength" in info.output and "floor F2" in info.output
    # an angle layer's values around their circular mean, not "range 0.0 .. 360.0"
    heading = re.search(r"layer heading_offset .* circular mean (-?[\d.]+), ([+-][\d.]+) \.\. "
                        r"([+-][\d.]+) around it", info.output)
    assert heading and -20 < float(heading[2]) <= 0 <= float(heading[3]) < 20, info.output
    assert "smoothing local_" in info.output and "bandwidth" in info.output  # what CV chose
    assert " % within 2 m" in info.output
    plan_sha = hashlib.sha256((SITE / "F2" / "geojson_map.json").read_bytes()).hexdigest()
    assert f"on floor plan geojson_map.json ({plan_sha[:12]}), floor_info.json (" in info.output
    assert load_bundle(a).manifest["build"]["floor_plan"][0] == {"file": "geojson_map.json",
                                                                 "sha256": plan_sha}
    diff = runner.invoke(main, ["bundle", "diff", str(a), str(tmp_path / "a" / "_site")])
    assert diff.exit_code == 0 and "of different sites, floors or kinds" in diff.output
    # from a registry, a floor's site bundle is the registry's current _site
    from mapping.radio_validation import _site_floor_model
    from mapping.registry import Registry

    reg = Registry(tmp_path / "reg")
    for name in ("F2", "_site"):
        reg.publish(tmp_path / "a" / name)
    floor = tmp_path / "reg" / load_bundle(a).site_id / "F2"
    model = load_bundle(tmp_path / "a" / "_site").manifest["metrics"]["floor_model"]
    assert model is not None and _site_floor_model(load_bundle(floor)) == model
    site = runner.invoke(main, ["bundle", "info", str(tmp_path / "a" / "_site")])
    assert site.exit_code == 0 and "site-level bundle" in site.output
    # the build's output folder: each bundle's summary under its path (before session 40:
    # "not a map bundle (no manifest.json)"), or its manifests keyed by folder name
    both = runner.invoke(main, ["bundle", "info", str(tmp_path / "a")])
    assert both.exit_code == 0, both.output
    assert f"{a}:\nbundle " in both.output and "site-level bundle" in both.output
    manifests = json.loads(runner.invoke(main, ["bundle", "info", "--json",
                                                str(tmp_path / "a")]).output)
    assert sorted(manifests) == ["F2", "_site"] and manifests["F2"] == load_bundle(a).manifest
    assert runner.invoke(main, ["bundle", "info", str(tmp_path / "reg")]).output.count(
        "\nbundle ") == 2  # a registry root: its floors' current versions (F2, _site)
    with pytest.raises(BundleError, match="a folder of bundles \\(F2, _site\\): give one of "
                       "them"):
        load_bundle(tmp_path / "a")  # what validate and the others say
    lower = tmp_path / "lower"  # the example given is a floor's, also where _site sorts first
    for name, src in (("level1", a), ("_site", tmp_path / "a" / "_site")):
        shutil.copytree(src, lower / name)
    with pytest.raises(BundleError, match=f"e.g. {lower / 'level1'}$"):
        load_bundle(lower)
    (lower / "_site" / "notes.txt").write_text("unlisted")  # one damaged bundle among them
    damaged = runner.invoke(main, ["bundle", "info", str(lower)])
    assert damaged.exit_code == 1 and f"{lower / 'level1'}:\nbundle " in damaged.output
    assert f"FAILED  {lower / '_site'}" in damaged.output
    assert (f"floor model (Wi-Fi, {model['transmitters']} transmitters): floors "
            f"{', '.join(model['floors'])}") in site.output
    verify = runner.invoke(main, ["bundle", "verify", str(a), str(tmp_path)])
    assert verify.exit_code == 1 and "ok " in verify.output and "FAILED" in verify.output


@pytest.mark.parametrize("args, message", [
    (["--cell", "0"], "Invalid value for '--cell'"),
    (["--cell", "nan"], "Invalid value for '--cell': nan is not a number"),
    (["--cell", "0.001"], "F2: a 40 x 25 m floor at 0.001 m cells is 1,000,000,000 cells, over "
                          "the limit of 20,000,000; check the plan's units (a floor drawn in "
                          "mm without units reads 1000 times too large), or raise --cell"),
    (["--cell", "1e-320"], "F2: a 40 x 25 m floor at 9.99989e-321 m cells is inf cells, over "
                           "the limit"),
    (["--cell", "100"], "F2: no cell centre of a 100 m grid lies in the plan's reachable area"),
    (["--build-time", "yesterday"], "not an ISO 8601 time"),
    (["-o", "FILE"], "is a file; -o/--out needs a folder"),
    (["--registry", "FILE"], "is a file; --registry needs a folder"),
])
def test_build_cli_refuses_bad_options_before_any_work(tmp_path, args, message):
    """Bad options are usage errors (exit 2) found before ingesting anything: no traceback
    after a whole build, no temporary store left."""
    (tmp_path / "FILE").write_text("keep me")
    args = [str(tmp_path / "FILE") if a == "FILE" else a for a in args]
    out = [] if "-o" in args else ["-o", str(tmp_path / "out")]
    res = CliRunner().invoke(main, ["build", str(SITE / "F2"), *out, *args])
    assert res.exit_code == 2 and message in res.output
    assert "ingest" not in res.output
    assert (tmp_path / "FILE").read_text() == "keep me" and not (tmp_path / "out").exists()


@pytest.mark.parametrize("given, hint", [
    ("{SITE}/F2/path_data_files", "its floor folder is {SITE}/F2"),  # the traces of a floor
    ("{SITE}/..", "it holds the site folder sample_site: build "),  # a folder of sites
    ("{tmp}", "a folder of traces needs its floor plan: --plan PLAN"),
])
def test_a_folder_that_is_no_floor_or_site_says_which_is(tmp_path, given, hint):
    """A floor's path_data_files or the folder above a site was refused with only "neither
    a floor folder nor a site folder"; the error now names the folder to give."""
    res = CliRunner().invoke(main, ["build", given.format(SITE=SITE, tmp=tmp_path), "-o",
                                    str(tmp_path / "o")])
    assert res.exit_code == 2, res.output
    assert hint.format(SITE=SITE) in res.output.replace("\n", " "), res.output


def test_a_site_floor_folder_without_its_plan_is_refused_not_passed_over(tmp_path):
    """A floor folder of a site with traces but no geojson_map.json (a plan not copied yet)
    was left out of `build SITE` without a word: exit 0, and the site's floor model made
    without that floor's walks. It is a usage error naming the floor, before any work."""
    site = tmp_path / "site"
    shutil.copytree(SITE, site)
    (site / "F2" / "geojson_map.json").unlink()
    res = CliRunner().invoke(main, ["build", str(site), "-o", str(tmp_path / "o")])
    assert res.exit_code == 2, res.output
    assert "the floor folder F2 of this site has no geojson_map.json" in " ".join(
        res.output.split())
    assert "ingest" not in res.output and not (tmp_path / "o").exists()


def test_a_broken_floor_info_is_named_with_its_line(tmp_path):
    floor = tmp_path / "F2"
    shutil.copytree(SITE / "F2", floor, ignore=shutil.ignore_patterns("path_data_files"))
    (floor / "path_data_files").mkdir()
    (floor / "floor_info.json").write_text('{"map_info":\n  {"width": 40,, "height": 25}}')
    res = CliRunner().invoke(main, ["build", str(floor), "-o", str(tmp_path / "out")])
    assert res.exit_code == 1
    assert f"{floor / 'floor_info.json'}:2: not valid JSON (Expecting property name enclosed " \
        "in double quotes: column 16)" in res.output


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")  # the NaN
@pytest.mark.parametrize("info, plan_edit, message", [
    ('{"map_info": {"width": 1e9, "height": 1e9}}', None, "floor_info.json: floor size 1e+09 x "
     "1e+09 m is over 20000 m on a side"),
    ('{"map_info": {"width": NaN, "height": 25}}', None, "is not a positive, finite size"),
    (None, lambda t: t.replace("]]", "], [NaN, 1.0]]", 1), "feature 0 has non-finite "
                                                             "coordinates"),
    (None, lambda t: '{"type": "FeatureCollection", "features": [1, 2]}',
     "feature 0 is not a GeoJSON feature"),
])
def test_bad_floor_plan_values_are_named_before_any_work(tmp_path, info, plan_edit, message):
    floor = tmp_path / "F2"
    shutil.copytree(SITE / "F2", floor)
    if info is not None:
        (floor / "floor_info.json").write_text(info)
    if plan_edit is not None:
        geo = floor / "geojson_map.json"
        geo.write_text(plan_edit(geo.read_text()))
    res = CliRunner().invoke(main, ["build", str(floor), "-o", str(tmp_path / "out")])
    assert res.exit_code == 1 and message in res.output, res.output
    assert "ingest" not in res.output and "Traceback" not in res.output


def test_a_repaired_floor_plan_is_said_before_the_work(tmp_path):
    floor = tmp_path / "F2"
    shutil.copytree(SITE / "F2", floor)
    geo = floor / "geojson_map.json"
    fc = json.loads(geo.read_text())
    ring = fc["features"][0]["geometry"]["coordinates"][0][0]  # a MultiPolygon's first ring
    ring[1], ring[2] = ring[2], ring[1]  # the outline's rectangle becomes a bow tie
    geo.write_text(json.dumps(fc))
    res = CliRunner().invoke(main, ["build", str(floor), "-o", str(tmp_path / "out"),
                                    "--cell", "0.001"])  # stops at the grid check
    assert res.exit_code == 2, res.output
    assert (f"warning: {geo}: feature 0 (the outline) is not a valid polygon "
            "(Self-intersection") in res.output


def test_a_floor_folder_given_as_dot_or_through_dot_dot(tmp_path, monkeypatch):
    """`build .` inside a floor folder, or `F2/path_data_files/..`, builds the folder they
    lead to, named by it (before, the floor name was "" or ".." and the build refused)."""
    shutil.copytree(SITE / "F2", tmp_path / "F2")
    monkeypatch.chdir(tmp_path / "F2")
    res = CliRunner().invoke(main, ["build", ".", "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert load_bundle(tmp_path / "out" / "F2").manifest["floor_name"] == "F2"
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, ["build", "F2/path_data_files/..", "-o", "out",
                                    "--cell", "0.001"])
    assert res.exit_code == 2 and "F2: a 40 x 25 m floor" in res.output


def test_a_floor_folder_named_otherwise_than_its_walks(tmp_path):
    """A floor folder whose walks are recorded as another floor is a usage error saying which
    floor; walks of another floor among the right ones are left out with a note."""
    floor = tmp_path / "floor1"
    shutil.copytree(SITE / "F1", floor)
    res = CliRunner().invoke(main, ["build", str(floor), "-o", str(tmp_path / "out")])
    assert res.exit_code == 2, res.output
    assert "its walks are recorded as floor F1, not floor1" in res.output
    assert not (tmp_path / "out").exists()
    f2 = tmp_path / "F2"
    shutil.copytree(SITE / "F2", f2)
    stray = sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0]
    shutil.copy(stray, f2 / "path_data_files")
    res = CliRunner().invoke(main, ["build", str(f2), "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert "left out of F2: 1 walk(s) in" in res.output and "recorded as floor F1" in res.output
    assert stray.name.split(".")[0] not in {
        w["trace_id"] for w in load_bundle(tmp_path / "out" / "F2").manifest["build"]
        ["source_walks"]}


def _build_then_kill(tmp_path, monkeypatch, crash_at):
    """Build F2 into ``tmp_path/out``, then build it again (build time 2030) in a process
    killed at ``crash_at``; the first build's bundle ids, ``out`` and the temporary folder."""
    import os
    import subprocess
    import sys
    import tempfile

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    out = tmp_path / "out"
    old = CliRunner().invoke(main, ["build", str(SITE / "F2"), "-o", str(out)])
    assert old.exit_code == 0, old.output
    ids = {n: load_bundle(out / n).bundle_id for n in ("F2", "_site")}
    killed = subprocess.run(
        [sys.executable, "-m", "survey.cli", "build", str(SITE / "F2"), "-o", str(out),
         "--overwrite", "--build-time", "2030-01-01T00:00:00Z"], capture_output=True, check=False,
        env={**os.environ, "INDOORMAP_CRASH_AT": crash_at, "TMPDIR": str(tmp)},
        cwd=Path(__file__).resolve().parents[1])
    assert killed.returncode == 70, killed.stderr.decode()
    return ids, out, tmp


def test_a_build_killed_before_its_last_bundle_leaves_the_old_set(tmp_path, monkeypatch):
    """A floor's bundle and its site bundle change together: a build that dies after writing
    the floor's new bundle but before the site's leaves both old ones (before: a new floor
    bundle next to the old site bundle, each verifying on its own); the next build cleans the
    dead build's staging folder and temporary store."""
    # died right after the floor's bundle was complete
    ids, out, tmp = _build_then_kill(tmp_path, monkeypatch, "bundle:after-rename")
    assert {n: load_bundle(out / n).bundle_id for n in ("F2", "_site")} == ids
    assert [p.name for p in out.iterdir() if p.name.startswith(".tmp-")]  # the dead stage
    assert list(tmp.glob("indoormap-build-*"))  # and its store
    again = CliRunner().invoke(main, ["build", str(SITE / "F2"), "-o", str(out), "--overwrite",
                                      "--build-time", "2030-01-01T00:00:00Z"])
    assert again.exit_code == 0, again.output
    assert sorted(p.name for p in out.iterdir()) == ["F2", "_site"]
    assert not list(tmp.iterdir())
    assert all(load_bundle(out / n).manifest["build"]["build_time"] == "2030-01-01T00:00:00Z"
               for n in ("F2", "_site"))


def test_a_build_killed_among_its_final_moves_is_finished_on_next_open(tmp_path, monkeypatch):
    """Killed after the floor's new bundle moved in but before the site bundle's: the folder
    held one new and one old bundle, each verifying on its own. Now the next open of either
    finishes the publication from its journal, so both are the killed build's."""
    _, out, _ = _build_then_kill(tmp_path, monkeypatch, "replace_together:after-0")
    assert load_bundle(out / "_site").manifest["build"]["build_time"] == "2030-01-01T00:00:00Z"
    assert load_bundle(out / "F2").manifest["build"]["build_time"] == "2030-01-01T00:00:00Z"
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".tmp-")) == [
        "F2", "_site"]


def test_sigterm_during_build_leaves_no_litter(tmp_path):
    """A build killed with SIGTERM (a job scheduler's stop) unwinds: its temporary store is
    removed and no output bundle appears."""
    import os
    import signal
    import subprocess
    import sys

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = subprocess.Popen(
        [sys.executable, "-m", "survey.cli", "build", str(SITE / "F2"), "-o",
         str(tmp_path / "out")], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
        env={**os.environ, "TMPDIR": str(tmp)}, cwd=Path(__file__).resolve().parents[1])
    for line in proc.stderr:  # the temporary store exists once processing has begun
        if line.startswith(b"process: "):
            break
    assert list(tmp.glob("indoormap-build-*"))
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM
    assert not list(tmp.glob("indoormap-build-*")) and not (tmp_path / "out").exists()


def _dxf_of(plan, path: Path, layers: tuple[str, str] = ("OUTLINE", "SHOPS")) -> None:
    """``plan`` (metres) drawn as a DXF: the outline on layer OUTLINE, obstacles on SHOPS
    (or the two ``layers``)."""
    import ezdxf
    import shapely

    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 6  # metres
    msp = doc.modelspace()
    for layer, geom in zip(layers, (plan.outline, plan.obstacles)):
        for poly in shapely.get_parts(geom):
            msp.add_lwpolyline(list(poly.exterior.coords)[:-1], close=True,
                               dxfattribs={"layer": layer})
    doc.saveas(path)


def test_build_cli_with_a_dxf_plan_and_a_folder_of_traces(tmp_path):
    """``build TRACES --plan plan.dxf``: a floor drawn in CAD builds like its floor folder; the
    floor's name comes from the traces, or from --floor when they hold several."""
    plan = read_floor_plan(SITE / "F2")
    _dxf_of(plan, tmp_path / "F2.dxf")
    runner = CliRunner()
    traces = SITE / "F2" / "path_data_files"
    res = runner.invoke(main, ["build", str(traces), "--plan", str(tmp_path / "F2.dxf"),
                               "-o", str(tmp_path / "dxf")])
    assert res.exit_code == 0, res.output
    folder = runner.invoke(main, ["build", str(SITE / "F2"), "-o", str(tmp_path / "folder")])
    assert folder.exit_code == 0, folder.output
    a, b = load_bundle(tmp_path / "dxf" / "F2"), load_bundle(tmp_path / "folder" / "F2")
    assert a.manifest["floor_name"] == "F2"
    # the same plan, the same maps; the manifests differ only by the plan files they name
    assert a.manifest["members"] == b.manifest["members"]
    assert [f["file"] for f in a.manifest["build"]["floor_plan"]] == ["F2.dxf"]
    assert bundle_differences(b, a)[0].startswith("floor plan: geojson_map.json (")
    # traces of two floors: the floor must be named
    two = tmp_path / "two"
    two.mkdir()
    for f in ("F1", "F2"):
        shutil.copytree(SITE / f / "path_data_files", two / f)
    res = runner.invoke(main, ["build", str(two), "--plan", str(tmp_path / "F2.dxf"),
                               "-o", str(tmp_path / "x")])
    assert res.exit_code == 2 and "walks of floors F1, F2; name the plan's floor" in res.output
    assert not (tmp_path / "x").exists()
    res = runner.invoke(main, ["build", str(two), "--plan", str(tmp_path / "F2.dxf"),
                               "--floor", "F2", "-o", str(tmp_path / "x")])
    assert res.exit_code == 0, res.output
    assert (load_bundle(tmp_path / "x" / "F2").manifest["build"]["source_walks"]
            == b.manifest["build"]["source_walks"])
    assert "warning" not in res.output
    # into an OUT that holds another floor's bundle: its _site will not model that floor
    shutil.copytree(tmp_path / "folder" / "F2", tmp_path / "x" / "F1")
    res = runner.invoke(main, ["build", str(two), "--plan", str(tmp_path / "F2.dxf"),
                               "--floor", "F2", "-o", str(tmp_path / "x"), "--overwrite"])
    assert res.exit_code == 0, res.output
    assert (f"warning: {tmp_path / 'x' / '_site'} will model floor F2 only; the bundles of F1 "
            f"in {tmp_path / 'x'} stay") in res.output
    for bad in ("_site", "../x", ""):  # names that are no floor bundle folder of OUT
        res = runner.invoke(main, ["build", str(two), "--plan", str(tmp_path / "F2.dxf"),
                                   "--floor", bad, "-o", str(tmp_path / "z")])
        assert res.exit_code == 2 and "cannot name a floor bundle folder" in res.output
    # a floor folder named so is refused before the work (before session 39: after the ingest)
    shutil.copytree(SITE / "F2", tmp_path / "site" / "_site")
    res = runner.invoke(main, ["build", str(tmp_path / "site"), "-o", str(tmp_path / "w")])
    assert res.exit_code == 2 and f"{tmp_path / 'site' / '_site'}: the folder name '_site' " \
        "cannot name a floor bundle folder ('_site' names the site bundle)" in res.output
    assert not (tmp_path / "w").exists() and "ingest" not in res.output
    res = runner.invoke(main, ["build", str(SITE / "F2"), "--floor", "F2",
                               "-o", str(tmp_path / "y")])
    assert res.exit_code == 2 and "--floor names the floor of a --plan build" in res.output


def test_a_plan_in_site_coordinates_builds_the_maps_of_the_floor_at_the_origin(tmp_path):
    """A floor drawn at (3000, 1000) in a site grid's metres, its walks recorded there: the
    map frame ran from (0, 0), so the 40 x 25 m floor asked for 3040 x 1025 m and was refused
    (at (2000, 1000) it built a 391 MB bundle in 6 minutes). The frame starts at the plan's
    corner: the bundle is the size of the one at the origin, with the same maps, moved; so at
    a UTM easting and northing (500 km, 4,000 km), whose walks were refused beyond 1,000 km."""
    from survey.trace_reader import read_trace
    from survey.walkline_writer import write_walk_plan

    plan = read_floor_plan(SITE / "F2")
    traces = [read_trace(p) for p in sorted((SITE / "F2" / "path_data_files").glob("*.txt.gz"))]
    bundles = {}
    for name, (dx, dy) in (("origin", (0.0, 0.0)), ("site", (3000.0, 1000.0)),
                           ("utm", (500_000.0, 4_000_000.0))):
        moved = dataclasses.replace(
            plan, outline=shapely.affinity.translate(plan.outline, dx, dy),
            obstacles=shapely.affinity.translate(plan.obstacles, dx, dy))
        _dxf_of(moved, tmp_path / f"{name}.dxf")
        walks = [dataclasses.replace(t, waypoints=t.waypoints.assign(
            x_m=t.waypoints.x_m + dx, y_m=t.waypoints.y_m + dy)) for t in traces]
        write_walk_plan(tmp_path / name, walks)
        res = CliRunner().invoke(main, ["build", str(tmp_path / name), "--plan",
                                        str(tmp_path / f"{name}.dxf"), "-o",
                                        str(tmp_path / f"{name}_out")])
        assert res.exit_code == 0, res.output
        bundles[name] = load_bundle(tmp_path / f"{name}_out" / "F2")
    near = bundles["origin"]
    for name, (dx, dy) in (("site", (3000, 1000)), ("utm", (500_000, 4_000_000))):
        far = bundles[name]
        assert (far.grid.width, far.grid.height) == (near.grid.width, near.grid.height)
        assert (far.grid.x0_m - near.grid.x0_m, far.grid.y0_m - near.grid.y0_m) == (dx, dy)
        np.testing.assert_array_equal(far.mask, near.mask)
        for layer in ("strength", "vertical", "heading_offset"):
            a, b = near.layers[layer], far.layers[layer]
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
            np.testing.assert_allclose(b, a, atol=1e-3, equal_nan=True)  # uT, deg
        x, y = np.array([10.0, 20.0, 30.0]), np.array([5.0, 12.5, 20.0])
        np.testing.assert_allclose(far.sample("strength", x + dx, y + dy),
                                   near.sample("strength", x, y), atol=1e-3, equal_nan=True)
    # and a walk is localized there as at the origin (float64 particles: no loss at 4,000 km)
    tracks = {}
    for name in ("origin", "utm"):
        res = CliRunner().invoke(main, ["localize", str(tmp_path / f"{name}_out" / "F2"),
                                        str(tmp_path / name / "plan.geojson"), "-o",
                                        str(tmp_path / f"{name}_loc"), "--no-plot",
                                        "--start", "waypoint", "--method", "indoormap"])
        assert res.exit_code == 0, res.output
        tracks[name] = pd.concat([pd.read_parquet(f) for f in
                                  sorted((tmp_path / f"{name}_loc").glob("*.parquet"))])
    apart = np.hypot(tracks["utm"]["x_m"].to_numpy() - 500_000 - tracks["origin"]["x_m"],
                     tracks["utm"]["y_m"].to_numpy() - 4_000_000 - tracks["origin"]["y_m"])
    assert len(apart) > 100 and np.median(apart) < 0.01


def test_a_plan_of_the_whole_building_builds_the_floor_named(tmp_path):
    """``build TRACES --plan building.geojson --floor F1`` with every floor's features in one
    file, tagged ``level``: the F1 maps are those built on F1's own plan (before, both floors'
    outlines were united and their shops cut out, silently); without --floor it is refused,
    naming the floors, before anything is ingested."""
    def features(plan, level):
        tag = {} if level is None else {"level": level}
        return [{"type": "Feature", "properties": {"role": "outline", **tag},
                 "geometry": shapely.geometry.mapping(plan.outline)}] + [
            {"type": "Feature", "properties": dict(tag), "geometry": shapely.geometry.mapping(p)}
            for p in shapely.get_parts(plan.obstacles)]

    f1, f2 = read_floor_plan(SITE / "F1"), read_floor_plan(SITE / "F2")
    files = {"building": features(f1, "F1") + features(f2, "F2"), "F1": features(f1, None)}
    traces, runner, bundles = SITE / "F1" / "path_data_files", CliRunner(), {}
    for name, feats in files.items():
        (tmp_path / f"{name}.geojson").write_text(json.dumps(
            {"type": "FeatureCollection", "features": feats}))
        res = runner.invoke(main, ["build", str(traces), "--plan",
                                   str(tmp_path / f"{name}.geojson"), "--floor", "F1", "-o",
                                   str(tmp_path / name)])
        assert res.exit_code == 0, res.output
        bundles[name] = tmp_path / name / "F1"
    layers = sorted(p.relative_to(bundles["F1"]) for p in bundles["F1"].rglob("*.npy"))
    assert len(layers) > 10
    for member in layers:
        assert (bundles["building"] / member).read_bytes() == \
            (bundles["F1"] / member).read_bytes(), member
    res = runner.invoke(main, ["build", str(traces), "--plan",
                               str(tmp_path / "building.geojson"), "-o", str(tmp_path / "x")])
    assert res.exit_code != 0 and "its features are of 2 floors (F1, F2)" in res.output
    assert "none is 'building'" in res.output and "ingest" not in res.output


def test_a_plan_in_utm_coordinates_has_a_frame_of_its_own_size(tmp_path):
    """A floor at a UTM easting and northing (500000, 4000000): refused before as over
    20 km on a side; now a frame of the floor's size from its corner, rounded to whole
    metres. Beyond the bundle's 1e8 m (a plan in mm or in some other unit) it is refused."""
    utm = _plan_file(tmp_path / "utm.geojson", 500_012.3, 4_000_007.6)
    plan = read_floor_plan(utm)
    assert (plan.x0_m, plan.y0_m) == (500_012, 4_000_007)
    assert plan.width_m == pytest.approx(40.3) and plan.height_m == pytest.approx(25.6)
    grid = plan.grid(0.25)
    assert (grid.width, grid.height) == (162, 103)
    with pytest.raises(FloorPlanError, match=r"beyond the 1e\+08 m a map's coordinates"):
        read_floor_plan(_plan_file(tmp_path / "far.geojson", 3e8, 0.0))


def _plan_file(path: Path, x0: float, y0: float) -> Path:
    """A 40 x 25 m metre GeoJSON floor from ``(x0, y0)`` with a 4 m shop in it."""
    def square(x, y, w, h):
        return [[[x, y], [x + w, y], [x + w, y + h], [x, y + h], [x, y]]]

    path.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"role": "outline"},
         "geometry": {"type": "Polygon", "coordinates": square(x0, y0, 40, 25)}},
        {"type": "Feature", "properties": {},
         "geometry": {"type": "Polygon", "coordinates": square(x0 + 10, y0 + 10, 4, 4)}}]}))
    return path


def test_dxf_layers_named_on_the_command_line(tmp_path):
    """An architect's layer names (A-FLOR-OTLN, A-FURN) are given with --dxf-layer; without
    them the error lists the drawing's layers and says how (only the Python API could)."""
    _dxf_of(read_floor_plan(SITE / "F2"), tmp_path / "F2.dxf", ("A-FLOR-OTLN", "A-FURN"))
    traces, runner = SITE / "F2" / "path_data_files", CliRunner()
    res = runner.invoke(main, ["build", str(traces), "--plan", str(tmp_path / "F2.dxf"),
                               "-o", str(tmp_path / "a")])
    assert res.exit_code == 1 and "found nothing; the drawing's entities are on layers " \
        "A-FLOR-OTLN, A-FURN (name yours: `indoormap build --dxf-layer outline=NAME`" \
        in res.output
    res = runner.invoke(main, ["build", str(traces), "--plan", str(tmp_path / "F2.dxf"),
                               "--dxf-layer", "outline=A-FLOR-OTLN", "--dxf-layer",
                               "obstacle=a-furn", "-o", str(tmp_path / "a")])
    assert res.exit_code == 0, res.output
    folder = runner.invoke(main, ["build", str(SITE / "F2"), "-o", str(tmp_path / "b")])
    assert folder.exit_code == 0, folder.output
    assert (load_bundle(tmp_path / "a" / "F2").manifest["members"]
            == load_bundle(tmp_path / "b" / "F2").manifest["members"])  # the same maps
    for args, message in ((["--dxf-layer", "floor=X"], "is not ROLE=LAYER with ROLE one of "
                            "outline, obstacle, wall"),
                          (["--dxf-layer", "outline="], "is not ROLE=LAYER")):
        res = runner.invoke(main, ["build", str(traces), "--plan", str(tmp_path / "F2.dxf"),
                                   *args, "-o", str(tmp_path / "c")])
        assert res.exit_code == 2 and message in res.output
    res = runner.invoke(main, ["build", str(SITE / "F2"), "--dxf-layer", "outline=X", "-o",
                               str(tmp_path / "c")])
    assert res.exit_code == 2 and "--dxf-layer names the layers of a DXF --plan" in res.output


def test_build_from_a_subset_of_walks_builds_that_subset(tmp_path):
    """A folder of symbolic links to some of a floor's traces builds from those walks; a kept
    store's other walks and the walks named by --exclude stay out of the maps (walks held out
    for evaluation must not leak into them)."""
    files = sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))
    store = tmp_path / "store"
    ingest([SITE / "F1" / "path_data_files"], store)  # a store that holds every walk
    train = tmp_path / "train"
    train.mkdir()
    for f in files[:-1]:
        (train / f.name).symlink_to(f)
    (tmp_path / "held.txt").write_text(f"# held out\n{files[1].name}\n")
    res = CliRunner().invoke(main, [
        "build", str(train), "--plan", str(SITE / "F1" / "geojson_map.json"),
        "--store", str(store), "--exclude", files[0].name.removesuffix(".txt.gz"),
        "--exclude", f"@{tmp_path / 'held.txt'}", "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert "left out: 1 walk(s) of the store not under" in res.output
    assert "excluded: 2 walk(s) (--exclude)" in res.output
    walks = load_bundle(tmp_path / "out" / "F1").manifest["build"]["source_walks"]
    assert sorted(w["trace_id"] for w in walks) == sorted(f.name.removesuffix(".txt.gz")
                                                          for f in files[2:-1])
    site_walks = load_bundle(tmp_path / "out" / "_site").manifest["build"]["source_walks"]
    assert site_walks == walks  # the fingerprints' and floor model's walks too
    res = CliRunner().invoke(main, [
        "build", str(train), "--plan", str(SITE / "F1" / "geojson_map.json"),
        "--exclude", "nosuch", "--exclude", files[-1].name, "-o", str(tmp_path / "other")])
    assert res.exit_code == 2 and "'nosuch' is no walk of this build" in res.output
    assert "1 more" in res.output  # the walk left out of the folder is none of its walks
    assert "ingest" not in res.output  # refused before the work
    assert not (tmp_path / "other").exists()
    # every walk excluded: said by floor, not by the build naming its temporary store
    (tmp_path / "all.txt").write_text("\n".join(f.name for f in files[:-1]))
    res = CliRunner().invoke(main, [
        "build", str(train), "--plan", str(SITE / "F1" / "geojson_map.json"),
        "--exclude", f"@{tmp_path / 'all.txt'}", "-o", str(tmp_path / "other")])
    assert res.exit_code == 2 and f"it leaves floor 'F1' no walk to build from (it names " \
        f"all {len(files) - 1})" in " ".join(res.output.split()), res.output
    assert "indoormap-build-" not in res.output.split("Error:")[-1]
    assert not (tmp_path / "other").exists()


def test_a_trace_of_another_site_in_a_floor_folder_is_refused(tmp_path):
    """A trace copied in from another building (another SiteID) was merged into the floor's
    maps, and the bundle took the site id of whichever walk sorted first (exit 0). The build
    now refuses, naming the trace; with it excluded the build goes on, with the site's id.
    The API refuses to merge sites too."""
    import gzip

    floor = tmp_path / "F2"
    shutil.copytree(SITE / "F2", floor)
    src = sorted((floor / "path_data_files").glob("*.txt.gz"))[0]
    text = gzip.decompress(src.read_bytes()).decode()
    site_id = text.split("SiteID:")[1].split("\t")[0]
    foreign = floor / "path_data_files" / "000foreign.txt.gz"
    foreign.write_bytes(gzip.compress(text.replace(site_id, "0" * len(site_id)).encode(),
                                      mtime=0))
    store = tmp_path / "store"
    res = CliRunner().invoke(main, ["build", str(floor), "-o", str(tmp_path / "out"),
                                    "--store", str(store)])
    assert res.exit_code == 1, res.output
    assert "walks of 2 sites (" in res.output and "000foreign.txt.gz" in res.output
    assert not (tmp_path / "out" / "F2").exists()
    process_store(store)
    with pytest.raises(BuildError, match=r"has walks of several sites \(\w+: \d+ walks"):
        build_floor(store, read_floor_plan(floor), floor="F2")
    with pytest.raises(FingerprintError, match=r"floors F2 have walks of several sites .*"
                                               r"00+: 1 walk\)"):
        build_site_radio(store, ["F2"])
    assert build_site_radio(store, ["F2"], site=site_id).floors == ["F2"]  # the site's alone
    res = CliRunner().invoke(main, ["build", str(floor), "-o", str(tmp_path / "out"),
                                    "--store", str(store), "--exclude", "000foreign"])
    assert res.exit_code == 0, res.output
    assert load_bundle(tmp_path / "out" / "F2").site_id == site_id


def test_a_build_ends_by_naming_its_damaged_inputs(tmp_path):
    """An unreadable file and a truncated one: the build goes on without the first and with
    the readable part of the second, and its last lines name both (they were said above the
    progress only, the truncated file not at all past the first five bad lines)."""
    floor = tmp_path / "F2"
    shutil.copytree(SITE / "F2", floor)
    files = sorted((floor / "path_data_files").glob("*.txt.gz"))
    data = files[0].read_bytes()
    files[0].write_bytes(data[:len(data) * 2 // 3])  # a copy cut short
    (floor / "path_data_files" / "noise.txt").write_bytes(b"\x00\xff garbage\n" * 10)
    res = CliRunner().invoke(main, ["build", str(floor), "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    tail = res.output[res.output.index("site: bundle"):]
    assert "warning: 1 input file(s) unreadable, left out of the maps: " \
        f"{floor / 'path_data_files' / 'noise.txt'}" in tail
    assert f"warning: 1 walk(s) built with bad lines skipped: {files[0]} (truncated 1)" in tail


def test_a_build_covering_little_of_its_floor_warns(tmp_path):
    """One walk maps a strip of the floor: the build says so (and names validate), where the
    whole survey does not warn."""
    floor = tmp_path / "F2"
    shutil.copytree(SITE / "F2", floor, ignore=shutil.ignore_patterns("path_data_files"))
    (floor / "path_data_files").mkdir()
    one = sorted((SITE / "F2" / "path_data_files").glob("*.txt.gz"))[0]
    shutil.copy(one, floor / "path_data_files")
    res = CliRunner().invoke(main, ["build", str(floor), "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    within_2m = load_bundle(tmp_path / "out" / "F2").manifest["metrics"]["coverage"]["within_2m"]
    assert within_2m < THIN_COVERAGE
    assert (f"warning: F2: only {100 * within_2m:.0f} % of the reachable area lies within 2 m"
            in res.output and "indoormap validate" in res.output)
    whole = CliRunner().invoke(main, ["build", str(SITE / "F2"), "-o", str(tmp_path / "all")])
    assert whole.exit_code == 0 and "warning: F2: only" not in whole.output


def test_traces_that_record_no_floor_are_their_folders_floor(tmp_path):
    """Walks whose headers name no floor were built as floor `unknown_floor`: a floor folder
    of them was refused ("recorded as floor unknown_floor, not F1") and `build --plan` named
    the bundle `unknown_floor`. Now they are the folder's floor, or the plan's (--floor, else
    the plan's folder's name), and the build says so."""
    import gzip

    traces = tmp_path / "F1" / "path_data_files"
    traces.mkdir(parents=True)
    for f in ("floor_info.json", "geojson_map.json"):
        shutil.copy(SITE / "F1" / f, tmp_path / "F1" / f)
    for src in sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[:6]:
        lines = gzip.decompress(src.read_bytes()).decode().splitlines(keepends=True)
        lines = [line.replace("\tFloorId:", "\tX:").replace("\tFloorName:", "\tY:")
                 if line.startswith("#") else line for line in lines]
        (traces / src.name.removesuffix(".gz")).write_text("".join(lines))
    runner = CliRunner()
    res = runner.invoke(main, ["build", str(tmp_path / "F1"), "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert f"6 walk(s) in {traces} record no floor: taken as F1" in res.output
    assert load_bundle(tmp_path / "out" / "F1").manifest["floor_name"] == "F1"
    plan = str(SITE / "F1" / "geojson_map.json")
    # into a kept store, then again as another floor: the walks move (they kept the first
    # floor, raw and processed, and the second build said its walks were recorded as G)
    for floor in ("G", "H"):
        res = runner.invoke(main, ["build", str(traces), "--plan", plan, "--floor", floor,
                                   "--store", str(tmp_path / "store"),
                                   "-o", str(tmp_path / f"named{floor}")])
        assert res.exit_code == 0, res.output
        assert f"6 walk(s) in {traces} record no floor: taken as {floor}" in res.output
        assert load_bundle(tmp_path / f"named{floor}" / floor).manifest["floor_name"] == floor
    assert not list((tmp_path / "store").rglob("floor=G"))  # nothing left of the first
    # without --floor: the plan's floor (a geojson_map.json: its folder's name)
    (tmp_path / "L3").mkdir()
    for f in ("floor_info.json", "geojson_map.json"):
        shutil.copy(SITE / "F1" / f, tmp_path / "L3" / f)
    res = runner.invoke(main, ["build", str(traces), "--plan",
                               str(tmp_path / "L3" / "geojson_map.json"),
                               "-o", str(tmp_path / "plan")])
    assert res.exit_code == 0, res.output
    assert "record no floor: taken as L3" in res.output
    assert load_bundle(tmp_path / "plan" / "L3").manifest["floor_name"] == "L3"


def test_a_plan_of_another_floor_is_refused_by_its_name(tmp_path):
    """``build F1/path_data_files --plan F2``: the bundle was built on F2's plan, with only
    its low coverage to show it. The plan names its floor (feature 0, as the ILC plans and
    the simulator's do): a usage error before anything is processed; ``--floor`` builds
    anyway, with a warning."""
    assert read_floor_plan(SITE / "F2").floor_name == "F2"
    runner, plan = CliRunner(), SITE / "F2" / "geojson_map.json"
    args = ["build", str(SITE / "F1" / "path_data_files"), "--plan", str(plan),
            "-o", str(tmp_path / "out")]
    res = runner.invoke(main, args)
    assert res.exit_code == 2, res.output
    assert (f"{plan} says it is the plan of floor F2, but the walks in "
            f"{SITE / 'F1' / 'path_data_files'} are recorded as floor F1; give floor F1's "
            "plan, or --floor F1 to build on this one") in res.output
    assert "process" not in res.output and not (tmp_path / "out").exists()
    res = runner.invoke(main, args + ["--floor", "F1"])
    assert res.exit_code == 0, res.output
    assert f"warning: {plan} says it is the plan of floor F2; building it as floor F1 " \
        "(--floor)" in res.output


def test_a_plans_floor_matches_walks_by_name_id_or_store_key(tmp_path):
    """The plan's floor name is compared with what the walks record: their floor name, id
    or store key (``Floor 2`` is stored as ``Floor_2``: the raw name against the key refused
    a right plan), and walks that record no floor are not checked, whatever the plan's file
    is called."""
    import click
    from mapping.cli_build import check_plan_floor
    from survey.ingest import IngestSummary
    from survey.store import IngestOutcome

    src = tmp_path / "traces"
    summary = IngestSummary(outcomes=[IngestOutcome(str(src / "a.txt"), "a", "new")])
    plan = dataclasses.replace(read_floor_plan(SITE / "F2"), floor_name="Floor 2")

    def walks(name, floor_id, key):
        return pd.DataFrame({"trace_id": ["a"], "floor_name": [name], "floor_id": [floor_id],
                             "floor": [key]})

    for ok in (walks("Floor 2", "", "Floor_2"), walks("", "Floor 2", "Floor_2"),
               walks("Floor_2", "", "Floor_2"), walks("", "", "plan_file_name")):
        check_plan_floor(plan, src / "p.geojson", ok, summary, src)
    with pytest.raises(click.UsageError, match="says it is the plan of floor Floor 2, but the "
                                               "walks in .* are recorded as floor F1"):
        check_plan_floor(plan, src / "p.geojson", walks("F1", "", "F1"), summary, src)


def test_a_survey_logged_in_gauss_is_refused_saying_so(tmp_path):
    """Walks converted with the magnetometer in gauss built a bundle whose field layers read
    0.4-0.5 "uT", without a word. Each walk is now skipped naming the unit, and the build
    ends saying every walk was skipped and why (it said to run `indoormap process`)."""
    from survey.trace_reader import read_trace
    from survey.walkline_writer import write_walk_plan

    def in_gauss(trace):
        sensors = trace.sensors.copy()
        mag = sensors["stream"].astype(str).str.startswith("magnetic")
        for col in ("x", "y", "z", "bx", "by", "bz"):
            sensors.loc[mag, col] = sensors.loc[mag, col] / 100
        return dataclasses.replace(trace, sensors=sensors)

    traces = sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[:2]
    plan = write_walk_plan(tmp_path / "gauss", [in_gauss(read_trace(p)) for p in traces])
    res = CliRunner().invoke(main, ["build", str(plan.parent), "--plan",
                                    str(SITE / "F1" / "geojson_map.json"), "-o",
                                    str(tmp_path / "out")])
    assert res.exit_code == 1 and not (tmp_path / "out" / "F1").exists()
    assert res.output.count("where the Earth's field is 25-65 uT: in gauss (1 G = 100 uT)? "
                            "indoormap reads uT") == 3  # two walks, then the summary
    assert "the store has no walk that processed: 2 skipped (the first, " in res.output
    assert "indoormap process" not in res.output
