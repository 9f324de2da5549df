"""``indoormap validate``: a spoiled simulated floor is flagged for exactly its three problems, the
clean one passes, metrics.json's held-out figures are mapping.holdout's, the HTML renders in a
headless browser with every image loaded."""

from __future__ import annotations

import html
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import validate_fixtures as vf
from click.testing import CliRunner

from localize.bundle import Grid, load_bundle
from mapping.holdout import (
    default_pipelines,
    floor_samples_with_baseline_positions,
    leave_one_walk_out,
)
from mapping.interpolate import RasterParams
from mapping.levelling import LevellingParams
from mapping.validate import (
    DEFAULT_THRESHOLDS,
    ValidateParams,
    ValidationError,
    line_accounts,
    load_thresholds,
    validate_bundle,
    walking_distance,
)
from survey.cli import main
from survey.store import SurveyStore

REPO = Path(__file__).resolve().parents[1]
HAS_MPL = importlib.util.find_spec("matplotlib") is not None  # figures and HTML need it
SECTIONS = ("problems", "checks", "coverage", "consistency", "heldout", "predicted",
            "calibration", "data-quality", "radio", "layers")


@pytest.fixture(scope="module")
def sites(tmp_path_factory):
    root = tmp_path_factory.mktemp("validate_site")
    clean = vf.clean_site(root / "clean")
    spoiled = vf.spoil_site(clean, root / "bad")
    return {"clean": (clean, *vf.build(clean, root / "work_clean")),
            "bad": (spoiled, *vf.build(spoiled.site, root / "work_bad"))}


def _validate(bundle: Path, store: Path | None, out: Path, *extra: str):
    args = ["validate", str(bundle), "-o", str(out), "-q", *extra]
    if store is not None:
        args += ["--store", str(store)]
    res = CliRunner().invoke(main, args)
    metrics = json.loads((out / "metrics.json").read_text()) if \
        (out / "metrics.json").exists() else None
    return res, metrics


@pytest.fixture(scope="module")
def reports(sites, tmp_path_factory):
    root = tmp_path_factory.mktemp("validate_reports")
    out = {}
    for name in ("clean", "bad"):
        _, bundle, store = sites[name]
        out[name] = _validate(bundle, store, root / name) + (root / name,)
    return out


def test_spoiled_site_flags_exactly_its_three_problems(sites, reports):
    spoiled: vf.Spoiled = sites["bad"][0]
    res, metrics, _ = reports["bad"]
    assert res.exit_code == 1, res.output
    assert metrics["verdict"] == "fail"
    fails = [f for f in metrics["findings"] if f["severity"] == "fail"]
    x0, y0, x1, y1 = spoiled.corridor_m
    found = {"offset": False, "waypoint": False, "corridor": False}
    for f in fails:
        if f["check"] == "walk_offset":
            assert f["walk"] == spoiled.offset_walk, f
            found["offset"] = True
        elif f["check"] == "leg_flags":
            assert f["walk"] == spoiled.waypoint_walk, f
            bx0, by0, bx1, by1 = f["where"]["bbox_m"]
            wx, wy = spoiled.waypoint_from
            assert bx0 - 3 <= wx <= bx1 + 3 and by0 - 3 <= wy <= by1 + 3, f
            found["waypoint"] = True
        elif f["check"] == "unsupported_region":
            cx, cy = f["where"]["x_m"], f["where"]["y_m"]
            assert x0 <= cx <= x1 and y0 <= cy <= y1, f  # inside the carved corridor
            assert f["where"]["area_m2"] > 20
            found["corridor"] = True
        elif f["check"] == "disagreement":  # a consequence of the bad walks, if any
            assert f["walk"] in (spoiled.offset_walk, spoiled.waypoint_walk), f
        else:
            pytest.fail(f"unexpected problem: {f}")
    assert all(found.values()), found
    # the summary names them too
    assert spoiled.offset_walk in res.output and spoiled.waypoint_walk in res.output
    assert "unsupported area" in res.output


def test_clean_site_passes(reports):
    res, metrics, out = reports["clean"]
    assert res.exit_code == 0, res.output
    assert metrics["verdict"] == "pass" and "PASS" in res.output
    assert not [f for f in metrics["findings"] if f["severity"] == "fail"]
    statuses = {c["check"]: c["status"] for c in metrics["checks"]}
    assert statuses["walk_offset"] == "pass" and statuses["unsupported_region"] == "pass"
    assert statuses["heldout_shape_rmse"] == "pass"
    if not HAS_MPL:
        return
    for name in ("overview", "coverage", "consistency", "heldout_cdf", "heldout_maps",
                 "predicted", "layers", "layers_std"):
        assert (out / "figures" / f"{name}.png").stat().st_size > 5000, name
    assert (out / "report.html").stat().st_size > 50000


def test_metrics_json_heldout_equals_mapping_holdout(sites, reports):
    """One implementation: the figures in metrics.json are leave_one_walk_out's own."""
    _, bundle, store = sites["clean"]
    _, metrics, _ = reports["clean"]
    ho = metrics["heldout"]
    p = ho["params"]
    b = load_bundle(bundle)
    samples = floor_samples_with_baseline_positions(SurveyStore.open(store), "F1")
    raster = RasterParams(**p["raster"])
    assert raster.bandwidth_m == b.manifest["metrics"]["bandwidth_m"]
    pipes = default_pipelines(raster)
    assert [q.name for q in pipes] == p["pipelines"]
    table = leave_one_walk_out(samples, b.grid, np.asarray(b.mask, bool), pipes,
                               layers=tuple(p["layers"]),
                               levelling=LevellingParams(**p["levelling"]),
                               levelling_folds=p["levelling_folds"], subsample=p["subsample"])
    got = pd.DataFrame(ho["table"]).set_index(["pipeline", "layer"])
    want = table.set_index(["pipeline", "layer"])
    assert set(got.index) == set(want.index)
    for key, row in want.iterrows():
        for col in ("rmse", "median_abs", "shape_rmse", "skill", "corr_0.7m", "corr_5m",
                    "n_samples", "n_walks", "coverage"):
            w, g = row[col], got.loc[key, col]
            if w is None or (isinstance(w, float) and np.isnan(w)):
                assert g is None or np.isnan(g), (key, col)
            else:
                assert g == w, (key, col, g, w)  # exactly, not approximately


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


CHECK_SCRIPT = """<script>
window.__errors = [];
window.addEventListener('error', function (e) {
  window.__errors.push(String(e.message || (e.target && e.target.tagName) || e.type));
}, true);
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var broken = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); });
  var out = document.createElement('pre');
  out.id = 'render-check';
  out.textContent = JSON.stringify({
    images: imgs.length, broken: broken.length,
    sections: Array.prototype.map.call(document.querySelectorAll('section[id]'),
                                       function (s) { return s.id; }),
    verdict: (document.getElementById('verdict') || {}).textContent || '',
    external: Array.prototype.filter.call(document.querySelectorAll('[src],[href]'),
      function (n) { var u = n.getAttribute('src') || n.getAttribute('href');
                     return !/^(data:|#)/.test(u); }).length,
    errors: window.__errors});
  document.body.appendChild(out);
});
</script>"""


def test_html_renders_in_headless_chromium(reports, tmp_path):
    pytest.importorskip("matplotlib")
    browser = _chromium()
    if browser is None:
        pytest.skip("chromium is not installed (apt-get install -y chromium)")
    for name in ("bad", "clean"):
        page = (reports[name][2] / "report.html").read_text(encoding="utf-8")
        assert "<script" not in page.lower()  # the report itself is static
        checked = tmp_path / f"{name}.html"
        checked.write_text(page.replace("<head>", "<head>" + CHECK_SCRIPT, 1),
                           encoding="utf-8")
        profile = tmp_path / f"profile-{name}"
        cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu",
               "--disable-background-networking", "--disable-component-update",
               "--disable-sync", "--no-first-run", "--disable-dev-shm-usage",
               f"--user-data-dir={profile}", "--virtual-time-budget=10000", "--dump-dom",
               checked.as_uri()]
        proc = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=180)
        m = re.search(r'<pre id="render-check">(.*?)</pre>', proc.stdout, re.DOTALL)
        assert m, (proc.returncode, proc.stderr[-2000:])
        info = json.loads(html.unescape(m.group(1)))
        assert info["errors"] == [], info
        assert info["images"] >= 8 and info["broken"] == 0, info
        assert info["external"] == 0, info
        assert set(SECTIONS) <= set(info["sections"]), info
        assert ("FAIL" if name == "bad" else "PASS") in info["verdict"]


def test_thresholds_file_overrides_and_rejects_unknown_keys(sites, tmp_path):
    _, bundle, store = sites["bad"]
    th = tmp_path / "th.json"
    th.write_text(json.dumps({"walk_offset_max_ut": 50, "unsupported_region_max_m2": None,
                              "leg_flags_fail": []}))
    res, metrics = _validate(bundle, store, tmp_path / "r1", "--thresholds", str(th),
                             "--no-holdout")
    assert res.exit_code == 0, res.output
    assert metrics["thresholds"]["walk_offset_max_ut"] == 50
    st = {c["check"]: c["status"] for c in metrics["checks"]}
    assert st["unsupported_region"] == "off" and st["walk_offset"] == "pass"
    # the flagged legs are still reported, as warnings
    assert any(f["check"] == "leg_flags" and f["severity"] == "warn"
               for f in metrics["findings"])
    th.write_text(json.dumps({"walk_ofset_max_ut": 5}))
    res, _ = _validate(bundle, store, tmp_path / "r2", "--thresholds", str(th))
    assert res.exit_code == 2 and "walk_ofset_max_ut" in res.output
    with pytest.raises(ValidationError, match="finite number"):
        load_thresholds(overrides={"walk_offset_max_ut": "x"})
    assert load_thresholds() == DEFAULT_THRESHOLDS


def test_python_thresholds_change_only_the_keys_given(sites):
    """validate_bundle(thresholds=...) takes what to change, as the file does: given one key
    it ran that check alone, and a misspelt key gave PASS on a floor that fails."""
    _, bundle, store = sites["bad"]
    params = ValidateParams(holdout=False, heading_holdout=False, radio=False)

    def statuses(thresholds):
        result = validate_bundle(bundle, store, thresholds=thresholds, params=params)
        return result, {c["check"]: c["status"] for c in result.metrics["checks"]}

    full, every = statuses(None)
    relaxed, some = statuses({"walk_offset_max_ut": 50})
    assert some.keys() == every.keys() and some["walk_offset"] == "pass"
    assert {k: v for k, v in some.items() if k != "walk_offset"} == \
        {k: v for k, v in every.items() if k != "walk_offset"}
    assert relaxed.thresholds["coverage_within_2m_min"] == DEFAULT_THRESHOLDS[
        "coverage_within_2m_min"]
    assert statuses({})[0].verdict == full.verdict == "fail"
    # a notebook shows the verdict, floor and failed checks, not every raster (44,000 lines)
    shown = repr(full)
    assert shown.startswith("ValidationResult('FAIL") and "walk_offset" in shown
    assert len(shown.splitlines()) == 1 and len(shown) < 1000, shown[:2000]
    with pytest.raises(ValidationError, match="walk_ofset_max_ut"):
        validate_bundle(bundle, store, thresholds={"walk_ofset_max_ut": 8}, params=params)


def test_without_store_checks_the_bundle_alone(sites, tmp_path):
    _, bundle, _ = sites["clean"]
    res, metrics = _validate(bundle, None, tmp_path / "r")
    assert res.exit_code == 0, res.output
    assert "heldout" not in metrics and metrics["coverage"]["source"].startswith("bundle")
    assert any(f["check"] == "no_store" for f in metrics["findings"])
    assert "warning: no survey store given (--store)" in res.output  # not only in the HTML
    # the verdict itself says how few checks ran (it read "PASS" alone)
    statuses = [c["status"] for c in metrics["checks"] if c["status"] != "off"]
    n_not_run = statuses.count("not run")
    assert n_not_run >= 5, statuses  # held-out, consistency, data quality
    assert (f": PASS ({len(statuses) - n_not_run} of {len(statuses)} checks ran; {n_not_run} "
            "not run: their input was missing)") in res.output
    assert (tmp_path / "r" / "report.html").exists() or not HAS_MPL


def test_a_bundle_built_without_a_walk_is_scored_without_it(sites, tmp_path, monkeypatch):
    """``build --exclude``, and a walk ingested after the build and not processed: the store
    holds both, but coverage, the held-out folds and the radio folds use the bundle's source
    walks only (they used all the store's processed walks, and an unprocessed one failed the
    report as 'not processed')."""
    import gzip

    import mapping.radio_validation as rv
    from mapping.build import build_floor
    from mapping.bundle_writer import write_bundle
    from mapping.floorplan import read_floor_plan
    from survey.ingest import ingest

    site, _, clean_store = sites["clean"]
    store = tmp_path / "store"
    shutil.copytree(clean_store, store)
    walks = sorted(SurveyStore.open(store).catalog()["trace_id"])
    left_out = walks[3]
    bundle = tmp_path / "bundle"
    write_bundle(bundle, build_floor(store, read_floor_plan(site / "F1"), floor="F1",
                                     exclude_walks=[left_out]))
    src = min((site / "F1" / "path_data_files").glob("*.txt.gz"))
    later = "a" * 22 + "01"
    (tmp_path / "later").mkdir()
    (tmp_path / "later" / f"{later}.txt.gz").write_bytes(gzip.compress(
        gzip.decompress(src.read_bytes()) + b"\n"))
    ingest([tmp_path / "later"], store)
    radio_walks: list[set] = []
    real = rv.heldout_radio

    def spy(obs, *args, **kwargs):
        radio_walks.append(set().union(*(set(o["trace_id"].astype(str)) for o in obs.values())))
        return real(obs, *args, **kwargs)

    monkeypatch.setattr(rv, "heldout_radio", spy)
    res, metrics = _validate(bundle, store, tmp_path / "r")
    assert res.exit_code in (0, 1), res.output
    manifest = json.loads((bundle / "manifest.json").read_text())
    assert metrics["store"]["walks"] == len(walks) - 1
    assert set(metrics["heldout"]["per_walk"]) == set(walks) - {left_out}
    assert metrics["coverage"]["euclidean"] == pytest.approx(manifest["metrics"]["coverage"])
    assert metrics["data_quality"]["walks_not_in_bundle"] == sorted([left_out, later])
    assert metrics["data_quality"]["store_matches_bundle"]
    assert not metrics["data_quality"]["walks_skipped"]
    checks = {f["check"]: f for f in metrics["findings"]}
    assert left_out in checks["walks_not_in_bundle"]["message"]
    assert "store_mismatch" not in checks and "walk_skipped" not in checks
    assert "2 walk(s) of the store not in the bundle left out" in res.output
    assert radio_walks == [set(walks) - {left_out}]
    assert str(metrics["store"]["path"]) == str(store)


def test_a_report_is_replaced_whole_and_only_when_asked(sites, tmp_path):
    """An existing report is kept without --overwrite (said before any work); with it, the
    new report replaces the old folder in one move. A folder that is no report is kept."""
    _, bundle, _ = sites["clean"]
    out = tmp_path / "r"
    first, _ = _validate(bundle, None, out)
    assert first.exit_code == 0, first.output
    (out / "old-note.txt").write_text("from the first run")
    again, _ = _validate(bundle, None, out)
    assert again.exit_code == 1 and f"{out} exists; pass --overwrite" in again.output
    assert (out / "old-note.txt").exists()
    replaced, metrics = _validate(bundle, None, out, "--overwrite")
    assert replaced.exit_code == 0 and metrics["verdict"] == "pass"
    assert not (out / "old-note.txt").exists()  # the folder was replaced, not written into
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".tmp-")]
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.txt").write_text("keep me")
    other, _ = _validate(bundle, None, tmp_path / "docs", "--overwrite")
    assert other.exit_code == 1 and "is not a validation report" in other.output
    assert (tmp_path / "docs" / "a.txt").read_text() == "keep me"
    # a report inside the bundle would make it fail its checks (session 39)
    inside = CliRunner().invoke(main, ["validate", str(bundle), "-o", str(bundle / "report"),
                                       "-q"])
    assert inside.exit_code == 2 and "is inside the map bundle" in inside.output
    assert not (bundle / "report").exists()


def test_an_output_under_a_file_is_refused_before_the_work(tmp_path, sites):
    """validate, simulate and survey-report ran their work (validate 37 s on a real floor),
    then said only "FILE: File exists" (read as: pass --overwrite) when a folder on the
    output's path was a file. It is said first, naming the file."""
    (tmp_path / "FILE").write_text("keep me")
    under = str(tmp_path / "FILE" / "sub")
    _, bundle, store = sites["clean"]
    for args in (["validate", str(bundle), "-o", under], ["simulate", under],
                 ["survey-report", "--store", str(store), "--csv", f"{under}.csv"]):
        res = CliRunner().invoke(main, args)
        assert res.exit_code in (1, 2) and f"{tmp_path / 'FILE'} is a file, not a folder: " \
            in " ".join(res.output.split()), (args, res.output)
    assert (tmp_path / "FILE").read_text() == "keep me"


def test_a_floor_dir_that_cannot_be_the_bundles_floor_is_said(sites, tmp_path):
    """--floor-dir was taken as given: an empty folder, or another floor's, drew the
    figures over nothing or over the other floor's image without a word."""
    site, bundle, _ = sites["clean"]
    (tmp_path / "empty").mkdir()
    other, renamed = tmp_path / "F1", tmp_path / "plans_of_f1"
    shutil.copytree(site / "F1", other, ignore=shutil.ignore_patterns("path_data_files"))
    shutil.copytree(other, renamed)  # the plan a --plan build used, in a folder named so
    plan = json.loads((other / "geojson_map.json").read_text())
    plan["features"][0]["properties"] = {"edited": True}  # another plan, under F1's name
    (other / "geojson_map.json").write_text(json.dumps(plan))
    for folder, said in ((tmp_path / "empty", "holds neither floor_image.png nor "
                                              "floor_info.json"),
                         (other, "its geojson_map.json is not the plan the bundle was built "
                                 "on (floor 'F1')"),
                         (renamed, None), (site / "F1", None)):
        res, metrics = _validate(bundle, None, tmp_path / f"r-{folder.parent.name}-"
                                 f"{folder.name}", "--floor-dir", str(folder))
        found = [f for f in metrics["findings"] if f["check"] == "floor_dir"]
        if said is None:
            assert not found and "--floor-dir" not in res.output, res.output
        else:
            assert said in found[0]["message"] and f"warning: --floor-dir {folder}" in \
                res.output and said in " ".join(res.output.split()), res.output


def test_usage_errors_exit_2(tmp_path):
    res = CliRunner().invoke(main, ["validate", str(tmp_path / "missing"), "-o",
                                    str(tmp_path / "o")])
    assert res.exit_code == 2
    res = CliRunner().invoke(main, ["validate", str(tmp_path)])
    assert res.exit_code == 2


def test_walking_distance_goes_around_walls():
    g = Grid(0.0, 0.0, 1.0, 7, 5)
    mask = np.ones(g.shape, bool)
    mask[0:4, 3] = False  # a wall with a gap at the top row
    support = np.zeros(g.shape, bool)
    support[0, 0] = True
    d = walking_distance(g, mask, support)
    assert d[0, 0] == 0 and np.isnan(d[0, 3])
    assert d[0, 4] > 6  # 4 m away in a straight line, around the wall on foot
    assert np.isclose(d[0, 2], 2.0) and np.isclose(d[1, 1], np.sqrt(2))
    mask2 = mask.copy()
    mask2[4, 3] = False  # now the right part is cut off
    assert np.isinf(walking_distance(g, mask2, support)[0, 6])


@pytest.mark.parametrize("floor", ["F1"])
def test_sample_bundle_from_data_is_fast(tmp_path, floor, sites):
    """The repository's sample (data/sample_site) validates well within 30 s. Another site's
    bundle of a floor of the same name is refused with that store, naming both sites,
    instead of being scored on walks it was not built from."""
    from mapping.build import build_floor
    from mapping.bundle_writer import write_bundle
    from mapping.floorplan import read_floor_plan
    from survey.ingest import ingest
    from survey.process_store import process_store

    site = REPO / "data" / "sample_site"
    ingest([site / floor / "path_data_files"], tmp_path / "store")
    process_store(tmp_path / "store")
    write_bundle(tmp_path / "b", build_floor(tmp_path / "store", read_floor_plan(site / floor),
                                             floor=floor))
    t = time.perf_counter()
    res, metrics = _validate(tmp_path / "b", tmp_path / "store", tmp_path / "r")
    took = time.perf_counter() - t
    assert res.exit_code in (0, 1) and metrics["heldout"]["table"]
    assert took < 90, took  # measured ~10 s; generous for loaded CI machines
    # the 6-walk sample leaves whole corridors unwalked: the report must say where
    assert any(f["check"] == "unsupported_region" for f in metrics["findings"])
    other = sites["clean"][1]  # a bundle of another simulated site's F1
    res, metrics = _validate(other, tmp_path / "store", tmp_path / "r2")
    sample_site = SurveyStore.open(tmp_path / "store").catalog()["site"].iloc[0]
    assert res.exit_code == 1 and metrics is None and not (tmp_path / "r2").exists()
    assert f"holds no walk of {other}'s site {load_bundle(other).site_id}, floor F1 (its F1 " \
        f"walks are of site {sample_site})" in res.output


def test_params_are_recorded(reports):
    _, metrics, _ = reports["clean"]
    assert metrics["params"] == ValidateParams().to_dict()
    assert metrics["heldout"]["implementation"] == "mapping.holdout.leave_one_walk_out"


def test_radio_section_reports_heldout_errors_and_bound(reports):
    _, metrics, out = reports["clean"]
    radio = metrics["radio"]
    assert radio["available"] and radio["primary_kind"] == "wifi"
    wifi = radio["kinds"]["wifi"]
    assert wifi["split"] == "leave-one-walk-out" and wifi["scans"] > 50
    assert 0 < wifi["median_error_m"] < 10 and wifi["p80_error_m"] >= wifi["median_error_m"]
    assert wifi["bound_m"]["cells"] > 100 and 0 < wifi["bound_m"]["median"] < 10
    assert radio["floor_accuracy"] is None and "no site bundle" in radio["floor_note"]
    if HAS_MPL:
        html = (out / "report.html").read_text()
        assert "held-out split" in html and "leave-one-walk-out" in html
        assert "whole-walk median" in html
    assert 0 < wifi["walk_median_error_m"] < 10


def test_radio_bound_of_two_linear_fields():
    """Two transmitters with orthogonal 2 dB/m gradients and 4 dB noise: J = diag(1/4, 1/4),
    bound sqrt(trace(J^-1)) = sqrt(8) m in the interior."""
    import pandas as pd

    from localize.bundle import Grid
    from mapping.fingerprints import FingerprintDB
    from mapping.radio_validation import radio_bound

    xs, ys = np.meshgrid(np.arange(0.5, 40), np.arange(0.5, 30))
    xy = np.column_stack([xs.ravel(), ys.ravel()])
    rp = pd.DataFrame({"rp_id": np.arange(len(xy)), "x_m": xy[:, 0], "y_m": xy[:, 1],
                       "n_scans": 4})
    fp = pd.concat([pd.DataFrame({"rp_id": rp["rp_id"], "ap": ap, "mean_dbm": -40 - 2 * xy[:, i],
                                  "var_db2": 16.0, "n": 4, "detection_rate": 1.0})
                    for i, ap in enumerate(["a", "b"])], ignore_index=True)
    db = FingerprintDB("wifi", rp, fp, 1.0, None)
    grid = Grid(0.0, 0.0, 0.5, 80, 60)
    bound = radio_bound(db, grid, np.ones(grid.shape, bool), cell_m=2.0, smooth_m=2.0)
    inner = bound[20:40, 20:60]
    assert np.isfinite(inner).all()
    np.testing.assert_allclose(inner, np.sqrt(8.0), rtol=0.05)


def test_metrics_json_radio_equals_heldout_radio(sites, reports):
    """One implementation: validate's radio errors are mapping.radio_validation.heldout_radio's
    (the function behind benchmarks/wifi_accuracy.py) on the same data."""
    from mapping.radio_build import site_observations
    from mapping.radio_validation import heldout_radio, walk_folds
    from survey.store import SurveyStore

    _, bundle, store = sites["clean"]
    _, metrics, _ = reports["clean"]
    st = SurveyStore.open(store)
    floor = load_bundle(bundle).manifest["floor_name"]
    obs = {k: site_observations(st, None, [floor], k) for k in ("wifi", "ble")}
    obs = {k: o for k, o in obs.items() if len(o)}
    device_of = st.catalog().set_index("trace_id")["device_model"].astype(str)
    walks = np.concatenate([o["trace_id"].to_numpy().astype(str) for o in obs.values()])
    err = heldout_radio(obs, device_of, [floor], walk_folds(walks, 0))
    for kind, k in metrics["radio"]["kinds"].items():
        if "median_error_m" not in k:
            continue
        e = err[(floor, kind)]
        e = e[np.isfinite(e)]
        assert k["scans"] == len(e)
        assert k["median_error_m"] == pytest.approx(float(np.median(e)), rel=1e-12)
        assert k["p80_error_m"] == pytest.approx(float(np.percentile(e, 80)), rel=1e-12)
        walk = err[(floor, f"{kind} walk")]
        walk = walk[np.isfinite(walk)]
        assert len(walk) == len(e)
        assert k["walk_median_error_m"] == pytest.approx(float(np.median(walk)), rel=1e-12)


def test_line_accounts_flag_walks_with_too_many_bad_lines():
    """A walk over the bad-line share is a finding that names the walk, its share, the reasons
    and the first bad line; one under it is only counted."""
    catalog = pd.DataFrame({
        "trace_id": ["clean", "damaged"], "n_lines": [1000, 1000], "n_bad_lines": [1, 30],
        "n_skipped_lines": [5, 0], "n_dropped_rows": [0, 2],
        "bad_json": ['{"non_numeric": 1}', '{"field_count": 10, "non_numeric": 20}'],
        "skipped_json": ['{"TYPE_BLUE": 5}', "{}"], "dropped_json": ["{}", '{"dup": 2}'],
        "messages_json": ['["a.txt:7: x"]', '["b.txt:12: TYPE_WIFI needs 5 values, got 1"]']})
    lines, findings = line_accounts(catalog, 0.01)
    assert [r["n_bad_lines"] for r in lines] == [1, 30]
    assert lines[1]["bad"] == {"field_count": 10, "non_numeric": 20}
    assert [f.walk for f in findings] == ["damaged"]
    assert findings[0].message == (
        "walk damaged (3.0 % of its lines): 30 bad line(s) skipped (field_count 10, "
        "non_numeric 20); first: b.txt:12: TYPE_WIFI needs 5 values, got 1")
    assert line_accounts(catalog, None)[1] == []


def test_plotting_leaves_the_callers_matplotlib_backend_alone(tmp_path):
    """In a notebook the inline backend must survive importing the report module (which
    once switched it to Agg at import) and drawing the error CDFs (matplotlib's object API,
    not pyplot's global state)."""
    pytest.importorskip("matplotlib")
    code = ("import matplotlib, numpy as np\n"
            "import mapping.report_html\n"
            "from localize.plots import plot_cdfs\n"
            f"assert plot_cdfs({str(tmp_path / 'cdf.png')!r}, {{'a': np.arange(5.0)}})\n"
            "print(matplotlib.get_backend())\n")
    env = {**os.environ, "MPLBACKEND": "svg"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "svg" and (tmp_path / "cdf.png").stat().st_size > 1000


@pytest.mark.parametrize("override, message", [
    ({"magnetic_resolution_m": -1}, "magnetic_resolution_m must be above 0"),
    ({"magnetic_resolution_m": 0}, "magnetic_resolution_m must be above 0"),
    ({"coverage_within_2m_min": -5}, "coverage_within_2m_min must be at least 0 and at most 1"),
    ({"bad_line_share_max": 1.5}, "at most 1"),
    ({"walk_offset_max_ut": -0.1}, "walk_offset_max_ut must be at least 0"),
])
def test_thresholds_out_of_their_range_are_refused(override, message):
    """A negative resolution used to reach matplotlib as a traceback; a negative share was
    taken and made a check meaningless."""
    with pytest.raises(ValidationError, match=message):
        load_thresholds(overrides=override)
    assert load_thresholds(overrides={"heldout_skill_min": -0.5})["heldout_skill_min"] == -0.5


def test_a_floor_image_too_large_or_without_a_floor_size_is_left_out(tmp_path):
    """The report draws floor_image.png under its maps; a small PNG whose header says
    20000 x 20000 pixels (6.4 GB decoded) is left out before decoding, as is one whose
    floor_info.json has no usable size, and the report says why."""
    from matplotlib.image import imsave

    from mapping.report_html import MAX_FLOOR_IMAGE_PIXELS, floor_image, png_size

    (tmp_path / "floor_info.json").write_text('{"map_info": {"width": 40, "height": 25}}')
    imsave(tmp_path / "floor_image.png", np.ones((50, 80)), cmap="gray")
    img, extent, source = floor_image(tmp_path)
    assert img.shape == (50, 80) and extent == (0.0, 40.0, 0.0, 25.0)
    assert source == str(tmp_path / "floor_image.png")
    assert png_size(tmp_path / "floor_image.png") == (80, 50)
    header = bytearray((tmp_path / "floor_image.png").read_bytes())
    header[16:24] = (20000).to_bytes(4, "big") * 2  # the IHDR's width and height
    (tmp_path / "floor_image.png").write_bytes(bytes(header))
    assert 20000 * 20000 > MAX_FLOOR_IMAGE_PIXELS
    img, extent, source = floor_image(tmp_path)
    assert img is None and extent is None and "left out (20000 x 20000 pixels" in source
    (tmp_path / "floor_info.json").write_text('{"map_info": {"width": NaN, "height": 25}}')
    assert "left out (floor size not positive" in floor_image(tmp_path)[2]
    assert floor_image(None) == (None, None, None)


def test_the_floor_folder_of_walk_line_walks_is_found(tmp_path):
    """The report finds the floor folder (for its plan and image) above the walks' sources:
    a trace in ``<floor>/path_data_files/``, and a walk-line log in
    ``<floor>/<survey>/logs/`` (it looked two levels up only, so walk-line surveys had none)."""
    from types import SimpleNamespace

    from mapping.validate import floor_dir_of

    floor = tmp_path / "F1"
    (floor / "survey" / "logs").mkdir(parents=True)
    (floor / "path_data_files").mkdir()
    (floor / "geojson_map.json").write_text("{}")
    for source in (floor / "path_data_files" / "a.txt", floor / "survey" / "logs" / "a.csv"):
        found = floor_dir_of(SimpleNamespace(catalog=pd.DataFrame({"source_path": [source]})))
        assert found == floor
    far = tmp_path / "x" / "y" / "z" / "w.csv"
    assert floor_dir_of(SimpleNamespace(catalog=pd.DataFrame({"source_path": [far]}))) is None


def test_a_colour_scale_that_clips_cells_says_so():
    """Colour bars whose scale clips cells (the uncertainty at its 98th percentile, radio
    errors at 10 m) drew them as the top colour, with nothing to tell a cell at 10 m from one
    at 40 m; the bar now ends in an arrow on the side it clips."""
    from matplotlib.colors import Normalize

    from mapping.report_html import _clipped

    values = np.ma.masked_invalid(np.array([[0.5, 3.0], [np.nan, 40.0]]))
    assert _clipped(values, Normalize(0, 10)) == "max"
    assert _clipped(values, Normalize(1, 50)) == "min"
    assert _clipped(values, Normalize(1, 10)) == "both"
    assert _clipped(values, Normalize(0, 40)) == "neither"
    assert _clipped(np.ma.masked_invalid(np.full((2, 2), np.nan)), Normalize(0, 1)) == "neither"


def test_a_regions_point_lies_inside_it_not_on_its_edge():
    """An L-shaped unsupported area (a room joined to a corridor) was said and marked at its
    cell nearest the centroid, on the region's edge against a wall; it is now a cell
    farthest from the edge."""
    from localize.bundle import Grid
    from mapping.validate import _regions

    grid = Grid(0.0, 0.0, 1.0, 40, 40)
    sel = np.zeros((40, 40), dtype=bool)
    sel[0:30, 0:3] = True  # a long corridor, 3 cells wide
    sel[27:30, 0:30] = True  # and another, joined at a corner: the centroid lies outside
    sel[5:15, 20:30] = True  # a room on its own
    _, regions = _regions(grid, sel)
    corridor, room = regions  # largest first
    assert room["area_m2"] == 100 and (room["x_m"], room["y_m"]) in \
        {(24.5, 9.5), (25.5, 9.5), (24.5, 10.5), (25.5, 10.5)}  # its middle
    r, c = int(corridor["y_m"]), int(corridor["x_m"])
    assert sel[r, c] and sel[r - 1:r + 2, c - 1:c + 2].all()  # inside, not on the edge
