"""The simulated site on disk: layout, map files, ground truth, determinism, read-back, size."""

from __future__ import annotations

import gzip
import hashlib
import json
import re
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from shapely.geometry import Point, Polygon

from survey.errors import PublishError
from survey.sim.cli import simulate
from survey.sim.field import MagneticField
from survey.sim.mapjson import GeoOrigin
from survey.sim.site import SiteParams, simulate_site

HEX24 = re.compile(r"[0-9a-f]{24}")
SAMPLES = ["t_ms", "x_m", "y_m", "heading_deg", "speed_mps", "field_e_ut", "field_n_ut",
           "field_u_ut", "compass_deviation_deg", "holding_mode", "qx", "qy", "qz", "qw"]


def _digests(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "site"
    t0 = time.perf_counter()
    site = simulate_site(SiteParams.preset_params("sample"), out)
    print(f"sample preset simulated in {time.perf_counter() - t0:.1f} s")
    return site, out, json.loads((out / "truth" / "site.json").read_text())


def test_sample_preset_shape(sample):
    site, _, truth = sample
    assert site.floors == ("F1", "F2")
    assert len(site.walks) == 12
    devices = {w.device_id for w in site.walks}
    sessions = {w.session_id for w in site.walks}
    assert len(devices) >= 2 and len(sessions) >= 4
    for d in devices:
        assert len({w.session_id for w in site.walks if w.device_id == d}) >= 2
    assert all(30.0 <= (w.end_ms - w.start_ms) / 1000 <= 75.0 for w in site.walks)
    assert sum(not w.has_wifi for w in site.walks) == 1
    assert truth["seed"] == 7 and truth["preset"] == "sample"


def test_layout(sample):
    site, out, truth = sample
    for floor in site.floors:
        for name in ("floor_info.json", "geojson_map.json", "planned_routes.geojson"):
            assert (out / floor / name).is_file()
        traces = sorted((out / floor / "path_data_files").glob("*.txt.gz"))
        assert len(traces) == 6
        for p in traces:
            tid = p.name[: -len(".txt.gz")]
            assert HEX24.fullmatch(tid)
            for suffix in (".parquet", ".steps.parquet", ".waypoints.parquet"):
                assert (out / "truth" / floor / f"{tid}{suffix}").is_file()
    assert {w["trace_id"] for w in truth["walks"]} == {w.trace_id for w in site.walks}
    for key in ("params", "site", "floors", "devices", "sessions", "walks", "radio"):
        assert key in truth
    for s in truth["sessions"]:
        assert len(s["true_hard_iron_ut"]) == 3 and len(s["reported_bias_ut"]) == 3
    assert not list(out.parent.glob(".tmp-*"))                # published atomically


def test_map_files_follow_the_real_layout(sample):
    site, out, _ = sample
    for floor in site.floors:
        info = json.loads((out / floor / "floor_info.json").read_text())
        w, h = info["map_info"]["width"], info["map_info"]["height"]
        gj = json.loads((out / floor / "geojson_map.json").read_text())
        feats = gj["features"]
        assert feats[0]["geometry"]["type"] == "MultiPolygon"
        assert all(f["geometry"]["type"] == "Polygon" for f in feats[1:]) and len(feats) > 5
        ring = np.asarray(feats[0]["geometry"]["coordinates"][0][0])
        lo, hi = ring.min(axis=0), ring.max(axis=0)
        scale = np.array([w, h]) / (hi - lo)
        # linear around the synthetic origin: degrees per metre as GeoOrigin states
        np.testing.assert_allclose((hi - lo) / np.array(GeoOrigin().deg_per_m), [w, h],
                                   rtol=1e-9)

        def to_m(lonlat, lo=lo, scale=scale):
            return (np.asarray(lonlat) - lo) * scale

        outline = Polygon(to_m(ring))
        shops = [Polygon(to_m(f["geometry"]["coordinates"][0])) for f in feats[1:]]
        assert outline.bounds == pytest.approx((0.0, 0.0, w, h), abs=1e-6)
        plan = json.loads((out / floor / "planned_routes.geojson").read_text())
        assert len(plan["features"]) == 6
        for feat in plan["features"]:
            props = feat["properties"]
            assert HEX24.fullmatch(props["walk_id"]) and props["start_ms"] < props["end_ms"]
            assert (out / floor / "path_data_files" / f"{props['walk_id']}.txt.gz").is_file()
            for x, y in feat["geometry"]["coordinates"]:
                p = Point(x, y)
                assert outline.contains(p)
                assert not any(s.contains(p) for s in shops)   # waypoints never inside shops


def test_ground_truth_tables(sample):
    site, out, truth = sample
    fields = {f["name"]: MagneticField.from_dict(f["field"]) for f in truth["floors"]}
    for w in site.walks:
        s = pd.read_parquet(out / w.truth_path)
        assert list(s.columns) == SAMPLES
        assert len(s) == w.n_samples and (np.diff(s["t_ms"]) > 0).all()
        assert set(s["holding_mode"].astype(str)) == {w.holding_mode}
        b = fields[w.floor].field_earth_ut(s["x_m"].to_numpy(float), s["y_m"].to_numpy(float))
        np.testing.assert_allclose(s[["field_e_ut", "field_n_ut", "field_u_ut"]], b, atol=0.01)
        steps = pd.read_parquet(out / f"truth/{w.floor}/{w.trace_id}.steps.parquet")
        assert len(steps) == w.n_steps and steps["length_m"].between(0, 1.0).all()
        clicks = pd.read_parquet(out / f"truth/{w.floor}/{w.trace_id}.waypoints.parquet")
        assert len(clicks) == w.n_waypoints


def test_traces_parse_back(sample):
    reader = pytest.importorskip("survey.trace_reader")
    site, out, truth = sample
    for w in site.walks:
        tr = reader.read_trace(out / w.trace_path, strict=True)
        assert tr.trace_id == w.trace_id
        assert tr.report.bad_total == 0
        assert tr.report.accounted_lines() == tr.report.lines_total
        assert tr.report.skipped.get("TYPE_BLUE", 0) == tr.report.skipped.get("TYPE_BLU4", 0) > 0
        assert tr.header.floor_name == w.floor and tr.header.start_ms == w.start_ms
        samples = pd.read_parquet(out / w.truth_path)
        for stream in ("accelerometer", "gyroscope", "magnetic_field", "rotation_vector",
                       "magnetic_field_uncalibrated"):
            np.testing.assert_array_equal(tr.stream(stream)["t_ms"], samples["t_ms"])
        cal = tr.stream("magnetic_field")[["x", "y", "z"]].to_numpy(np.float64)
        unc = tr.stream("magnetic_field_uncalibrated")
        bias = unc[["bx", "by", "bz"]].to_numpy(np.float64)
        np.testing.assert_allclose(cal, unc[["x", "y", "z"]].to_numpy(np.float64) - bias,
                                   atol=1e-3)
        session = next(s for s in truth["sessions"] if s["session_id"] == w.session_id)
        np.testing.assert_allclose(bias[0], session["reported_bias_ut"], atol=1e-4)
        rv = tr.stream("rotation_vector")[["x", "y", "z"]].to_numpy(np.float64)
        assert (np.sum(rv ** 2, axis=1) <= 1.0 + 1e-6).all()
        assert len(tr.waypoints) == w.n_waypoints
        assert (len(tr.wifi) > 0) == w.has_wifi
        if w.has_wifi:
            assert tr.wifi["bssid"].str.fullmatch(r"[0-9a-f]{2}(:[0-9a-f]{2}){5}").all()


def test_same_seed_same_bytes_via_cli(sample, tmp_path):
    _, out, _ = sample
    again = tmp_path / "again"
    res = CliRunner().invoke(simulate, [str(again), "--preset", "sample", "--seed", "7"])
    assert res.exit_code == 0, res.output
    assert "12 walks" in res.output
    assert _digests(again) == _digests(out)


def test_existing_output_needs_overwrite(sample):
    _, out, _ = sample
    with pytest.raises(PublishError):
        simulate_site(SiteParams.preset_params("sample"), out)
    from survey.cli import main

    before = _digests(out)
    res = CliRunner().invoke(main, ["simulate", str(out)])  # the CLI says so before any work
    assert res.exit_code == 1 and f"{out} exists; pass --overwrite" in res.output
    assert _digests(out) == before


def test_overwrite_replaces_only_a_simulated_site(tmp_path):
    """--overwrite on a folder that is not a simulated site (a typo in OUT_DIR) keeps it."""
    from survey.cli import main

    (tmp_path / "thesis").mkdir()
    (tmp_path / "thesis" / "chapter1.tex").write_text("keep me")
    res = CliRunner().invoke(main, ["simulate", str(tmp_path / "thesis"), "--overwrite"])
    assert res.exit_code == 1 and "is not a simulated site" in res.output
    assert (tmp_path / "thesis" / "chapter1.tex").read_text() == "keep me"


def test_overwrite_keeps_what_a_user_added_to_a_simulated_site(tmp_path):
    """A build's bundles and store kept in the site folder (or a note beside a floor's files)
    made --overwrite delete them without a word; now it refuses, naming them, and a clean
    simulated site is still replaced."""
    from survey.cli import main

    small = {"n_floors": 1, "walks_per_floor": 2, "walk_duration_s": (20.0, 25.0),
             "walks_without_wifi": 0}
    site = tmp_path / "site"
    simulate_site(SiteParams.preset_params("sample", seed=1, **small), site)
    (site / "bundles").mkdir()
    (site / "F1" / "notes.txt").write_text("keep me")
    extra = site / "F1" / "path_data_files" / "mine.txt"
    extra.write_text("a real trace")
    res = CliRunner().invoke(main, ["simulate", str(site), "--overwrite"])
    assert res.exit_code == 1, res.output
    assert "holds files the simulator did not write (F1/notes.txt, " in res.output
    assert "F1/path_data_files/mine.txt" in res.output and "bundles" in res.output
    assert (site / "F1" / "notes.txt").read_text() == "keep me" and extra.exists()
    for p in (site / "bundles", site / "F1" / "notes.txt", extra):
        p.rmdir() if p.is_dir() else p.unlink()
    res = CliRunner().invoke(main, ["simulate", str(site), "--overwrite"])
    assert res.exit_code == 0, res.output


def test_different_seed_different_files(tmp_path):
    small = {"n_floors": 1, "walks_per_floor": 2, "walk_duration_s": (20.0, 25.0),
             "walks_without_wifi": 0}
    a = tmp_path / "a"
    b = tmp_path / "b"
    simulate_site(SiteParams.preset_params("sample", seed=1, **small), a)
    simulate_site(SiteParams.preset_params("sample", seed=2, **small), b)
    da, db = _digests(a), _digests(b)
    assert set(da.values()).isdisjoint(
        v for k, v in db.items() if not k.endswith("floor_info.json"))
    simulate_site(SiteParams.preset_params("sample", seed=1, **small), a, overwrite=True)
    assert _digests(a) == da


def test_one_seed_two_layouts_are_two_sites(tmp_path):
    """Site and floor ids derive from the seed and the layout: two presets (or any other
    parameters) with one seed are two sites, so a registry or a localizer cannot take one for
    the other; the names alone do not make another site."""
    small = {"n_floors": 1, "walks_per_floor": 1, "walk_duration_s": (20.0, 25.0),
             "walks_without_wifi": 0}
    ids = {}
    for name, params in {
            "sample": SiteParams.preset_params("sample", **small),
            "wider": SiteParams.preset_params("sample", width_m=44.0, **small),
            "renamed": SiteParams.preset_params("sample", site_name="Other name", **small),
    }.items():
        truth = simulate_site(params, tmp_path / name)
        site = json.loads((tmp_path / name / "truth" / "site.json").read_text())
        ids[name] = (site["site"]["site_id"], site["floors"][0]["floor_id"])
        assert truth.site_id == ids[name][0]
    assert ids["sample"][0] != ids["wider"][0] and ids["sample"][1] != ids["wider"][1]
    assert ids["sample"] == ids["renamed"]
    default, sample = (SiteParams.preset_params(n) for n in ("default", "sample"))
    assert default.seed == sample.seed and default.layout_key() != sample.layout_key()


def test_sample_is_small(sample):
    _, out, _ = sample
    total = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    print(f"sample site: {total / 1e6:.2f} MB")
    assert total < 5_000_000
    for p in out.rglob("*.txt.gz"):
        with gzip.open(p, "rb") as fh:
            assert fh.read(2) == b"#\t"


@pytest.mark.parametrize("override, message", [
    ({"width_m": -40.0}, r"floor size -40.0 x 25.0 m: each side must be 10 to 2000 m"),
    ({"height_m": float("nan")}, "each side must be 10 to 2000 m"),
    ({"ew_corridor_widths_m": (5.0, 0.0)}, "corridor widths must be positive metres"),
    ({"marker_spacing_m": 0.0}, "marker_spacing_m must be > 0"),
    ({"walks_without_wifi": -1}, "walks_without_wifi must be >= 0"),
    ({"epoch_ms": -5}, "epoch_ms must be a Unix time in ms"),
])
def test_nonsense_site_parameters_are_refused_before_any_work(tmp_path, override, message):
    """A corridor of no width or an epoch before 1970 made a site; a marker spacing of 0 or
    a negative count crashed deep in the generator (OverflowError, ValueError), and a
    negative floor size was refused for its corridors. Each is refused by name."""
    from survey.errors import SimulationError

    with pytest.raises(SimulationError, match=message):
        simulate_site(SiteParams(**override), tmp_path / "site")
    assert not (tmp_path / "site").exists()
