"""`indoormap process` / `survey-report` over a store: results kept, skips explained."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from survey.cli import main
from mapping.floorplan import plan_floor_name
from survey.errors import ProcessingError, StoreError
from survey.ingest import ingest
from survey.process_store import process_store, processed_catalog, processed_table
from survey.trace_reader import read_trace
from survey.trace_writer import write_trace

SITE = Path(__file__).resolve().parents[1] / "data" / "sample_site"


def test_process_cli_and_report(tmp_path):
    floor = SITE / "F1"
    traces = sorted((floor / "path_data_files").glob("*.txt.gz"))[:3]
    # one walk with a single waypoint: it must be skipped with its reason, not lost
    bad = read_trace(traces[2])
    bad.waypoints = bad.waypoints.iloc[:1]
    write_trace(tmp_path / "in" / "single.txt.gz", bad)
    # one walk whose phone's calibrated field and bias are implausible: it needs our fit
    raw = read_trace(traces[1])
    cal = raw.sensors["stream"] == "magnetic_field"
    raw.sensors.loc[cal, ["x", "y", "z"]] *= 10
    raw.sensors.loc[raw.sensors["stream"] == "magnetic_field_uncalibrated",
                    ["bx", "by", "bz"]] = 500.0
    write_trace(tmp_path / "in" / "raw.txt.gz", raw)
    ingest([traces[0], tmp_path / "in"], tmp_path / "store")
    runner = CliRunner()
    res = runner.invoke(main, ["process", "--store", str(tmp_path / "store"),
                               "--floor-plan", str(floor)])
    assert res.exit_code == 0, res.output
    assert "processed 2, unchanged 0, skipped 1" in res.output
    assert "skipped single: a walk needs at least two waypoints" in res.output
    assert "calibration: 1 device-calibrated, 1 not-calibrated" in res.output
    # only the session that needed our pooled fit is listed (flat-held: ill-conditioned)
    listed = res.output.split("needing our pooled fit:\n")[1].strip().splitlines()
    assert len(listed) == 1 and "ill-conditioned" in listed[0]
    cat = processed_catalog(tmp_path / "store")
    assert sorted(cat["status"]) == ["ok", "ok", "skipped"]
    samples = processed_table(tmp_path / "store", "samples", floor="F1")
    assert samples["trace_id"].nunique() == 2 and samples[["x_m", "y_m"]].notna().all().all()
    with pytest.raises(ProcessingError, match=r"floor='1F'; the store has processed walks of "
                       r"site \S+ floors F1 \(2\)$"):  # a misspelt floor names the real ones
        processed_table(tmp_path / "store", "samples", floor="1F")
    wifi = processed_table(tmp_path / "store", "wifi")
    assert {"x_m", "y_m", "bssid", "rssi_dbm", "age_ms"} <= set(wifi.columns)
    again = runner.invoke(main, ["process", "--store", str(tmp_path / "store"),
                                 "--floor-plan", str(floor)])
    assert "processed 0, unchanged 3, skipped 0" in again.output  # nothing changed: no work
    assert "calibration: 1 device-calibrated, 1 not-calibrated" in again.output
    # the floor plan is an input (it flags legs leaving the reachable area): without it the
    # walks are processed again (they were called unchanged)
    again = runner.invoke(main, ["process", "--store", str(tmp_path / "store")])
    assert "processed 2, unchanged 0, skipped 1" in again.output
    report = runner.invoke(main, ["survey-report", "--store", str(tmp_path / "store"),
                                  "--csv", str(tmp_path / "qa.csv")])
    assert report.exit_code == 0, report.output
    assert "device-calibrated" in report.output and "flagged legs by reason" in report.output
    assert (tmp_path / "qa.csv").read_text().startswith("trace_id,floor,status,steps")
    # why a walk was skipped is a sentence after the table (it filled the calibration cell,
    # and the walk's id was said twice), and the CSV's reason column
    assert "\nskipped single: a walk needs at least two waypoints" in report.output
    qa = pd.read_csv(tmp_path / "qa.csv", keep_default_na=False)
    assert qa.set_index("trace_id").loc["single", "reason"].startswith("a walk needs at least")
    assert (qa["calibration"] != qa["reason"]).all()
    again = runner.invoke(main, ["survey-report", "--store", str(tmp_path / "store"),
                                 "--csv", str(tmp_path / "qa.csv")])
    assert again.exit_code == 1 and "qa.csv exists; pass --overwrite" in again.output
    for command in ("process", "survey-report"):  # a floor the store does not hold
        res = runner.invoke(main, [command, "--store", str(tmp_path / "store"), "--floor", "F9"])
        assert res.exit_code == 2 and "no walks for floor F9; the store has" in res.output
        assert "/F1 (site/floor)" in res.output


def test_process_without_processing_says_so(tmp_path):
    ingest([sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0]], tmp_path / "s")
    res = CliRunner().invoke(main, ["survey-report", "--store", str(tmp_path / "s")])
    assert res.exit_code == 1 and "not processed yet" in res.output


def test_processing_a_store_without_walks_says_to_ingest(tmp_path):
    """A store with no walks (made by the API): `process` said "processed 0" and then "not
    processed yet; run `indoormap process`". A failed ingest leaves no store at all, which
    `process` says too."""
    from survey.store import SurveyStore

    SurveyStore.create(tmp_path / "s")
    res = CliRunner().invoke(main, ["process", "--store", str(tmp_path / "s")])
    assert res.exit_code == 1 and "the store holds no walks; ingest traces" in res.output
    assert "not processed yet" not in res.output
    (tmp_path / "notatrace.txt").write_text("hello\n")
    res = CliRunner().invoke(main, ["ingest", str(tmp_path / "notatrace.txt"), "--store",
                                    str(tmp_path / "s2")])
    assert res.exit_code == 1
    res = CliRunner().invoke(main, ["process", "--store", str(tmp_path / "s2")])
    assert res.exit_code == 2 and "s2' does not exist" in res.output


def test_floor_plan_files_name_their_floor(tmp_path):
    """``--floor-plan plans/F1.dxf`` is F1's plan (legs leaving it are flagged); a plan for a
    floor without walks is said so, not silently ignored."""
    import ezdxf

    assert plan_floor_name(SITE / "F1") == "F1"
    assert plan_floor_name(SITE / "F1" / "geojson_map.json") == "F1"
    assert plan_floor_name(Path("plans/F2.dxf")) == "F2"
    (tmp_path / "plans").mkdir()
    for name in ("F1", "F7"):  # a 2 m square in a corner: every leg leaves it
        doc = ezdxf.new()
        doc.modelspace().add_lwpolyline([(0, 0), (2, 0), (2, 2), (0, 2)], close=True,
                                        dxfattribs={"layer": "OUTLINE"})
        doc.saveas(tmp_path / "plans" / f"{name}.dxf")
    ingest(sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[:1], tmp_path / "store")
    res = CliRunner().invoke(main, ["process", "--store", str(tmp_path / "store"),
                                    "--floor-plan", str(tmp_path / "plans" / "F1.dxf"),
                                    "--floor-plan", str(tmp_path / "plans" / "F7.dxf")])
    assert res.exit_code == 0, res.output
    assert "F7.dxf: no walks of floor 'F7' to check against this plan (floors: F1)" in res.output
    legs = processed_table(tmp_path / "store", "legs")
    assert legs["flags"].str.contains("off_floor").all()
    # two plans of one floor: the last one was used, unsaid; the same one twice is one
    res = CliRunner().invoke(main, ["process", "--store", str(tmp_path / "store"),
                                    "--floor-plan", str(tmp_path / "plans" / "F1.dxf"),
                                    "--floor-plan", str(SITE / "F1")])
    assert res.exit_code == 2 and "F1.dxf and " in res.output and "are both plans of floor " \
        "'F1'" in " ".join(res.output.split()), res.output
    res = CliRunner().invoke(main, ["process", "--store", str(tmp_path / "store"),
                                    "--floor-plan", str(SITE / "F1"),
                                    "--floor-plan", str(SITE / "F1" / "geojson_map.json")])
    assert res.exit_code == 0, res.output


def test_a_plan_of_several_floors_serves_each_of_its_floors(tmp_path):
    """``--floor-plan building.geojson`` holding every floor (features tagged ``level``) is
    read for each floor the walks are on; it was read for the floor its file name gives
    (``building``), which it does not hold, and refused."""
    import json

    import shapely

    from mapping.floorplan import plan_levels, read_floor_plan

    square = shapely.box(0, 0, 2, 2)  # F1: a 2 m square in a corner, every leg leaves it
    f2 = read_floor_plan(SITE / "F2")
    feats = [{"type": "Feature", "geometry": shapely.geometry.mapping(g),
              "properties": {"role": "outline", "level": level}}
             for g, level in ((square, "F1"), (f2.outline, "F2"), (square, "F9"))]
    feats += [{"type": "Feature", "geometry": shapely.geometry.mapping(p),
               "properties": {"level": "F2"}} for p in shapely.get_parts(f2.obstacles)]
    building = tmp_path / "building.geojson"
    building.write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    assert plan_levels(building) == ["F1", "F2", "F9"] and plan_levels(SITE / "F1") == ["F1"]
    ingest([sorted((SITE / floor / "path_data_files").glob("*.txt.gz"))[0]
            for floor in ("F1", "F2")], tmp_path / "store")
    res = CliRunner().invoke(main, ["process", "--store", str(tmp_path / "store"),
                                    "--floor-plan", str(building)])
    assert res.exit_code == 0, res.output
    assert f"{building}: read for floor F1 of F1, F2, F9" in res.output
    assert f"{building}: read for floor F2 of F1, F2, F9" in res.output
    off = {floor: processed_table(tmp_path / "store", "legs", floor=floor)["flags"]
           .str.contains("off_floor").mean() for floor in ("F1", "F2")}
    assert off["F1"] == 1.0 and off["F2"] < 0.5  # each floor checked against its own plan
    res = CliRunner().invoke(main, ["process", "--store", str(tmp_path / "store"),
                                    "--floor-plan", str(building), "--floor", "F9"])
    assert res.exit_code == 2  # no walks of F9 (a usage error, as before)
    res = CliRunner().invoke(main, ["process", "--store", str(tmp_path / "store"),
                                    "--floor", "F1", "--floor-plan", str(building)])
    assert res.exit_code == 0 and "read for floor F2" not in res.output
    other = tmp_path / "other.geojson"
    other.write_text(json.dumps({"type": "FeatureCollection", "features": feats[2:3] + [
        dict(feats[2], properties={"role": "outline", "level": "F8"})]}))
    res = CliRunner().invoke(main, ["process", "--store", str(tmp_path / "store"),
                                    "--floor-plan", str(other)])
    assert res.exit_code == 0 and f"{other}: no walks of any of its floors (F8, F9) to check " \
        "against this plan (floors: F1, F2)" in res.output
    # a file of one floor, its features tagged with it, serves that floor whatever its name
    one = tmp_path / "level2.geojson"
    one.write_text(json.dumps({"type": "FeatureCollection",
                               "features": [f for f in feats if f["properties"]["level"] == "F2"]}))
    assert plan_levels(one) == ["F2"]
    res = CliRunner().invoke(main, ["process", "--store", str(tmp_path / "store"),
                                    "--floor-plan", str(one)])
    assert res.exit_code == 0 and "no walks of" not in res.output, res.output
    assert not processed_table(tmp_path / "store", "legs", floor="F2")["flags"].str.contains(
        "off_floor").any()


PROCESS_OTHER_PARAMS = """
import sys
from survey.positions import PositionParams
from survey.process import ProcessParams
from survey.process_store import process_store
process_store(sys.argv[1], params=ProcessParams(positions=PositionParams(method="time")))
"""


def test_a_run_with_other_parameters_that_dies_leaves_the_old_results(tmp_path):
    """Processed files were named by the raw file alone and overwritten in place: a run with
    other parameters killed before its catalog switch left the other parameters' positions
    under the old catalog, and the next run called them unchanged."""
    traces = sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[:2]
    ingest(traces, tmp_path / "store")
    process_store(tmp_path / "store")
    before = processed_table(tmp_path / "store", "samples")
    env = {**os.environ, "INDOORMAP_CRASH_AT": "process:before-catalog"}
    proc = subprocess.run([sys.executable, "-c", PROCESS_OTHER_PARAMS, str(tmp_path / "store")],
                          env=env, capture_output=True)
    assert proc.returncode == 70, proc.stderr.decode()
    pd.testing.assert_frame_equal(processed_table(tmp_path / "store", "samples"), before)
    report = process_store(tmp_path / "store")
    assert len(report.unchanged) == 2 and not report.processed
    pd.testing.assert_frame_equal(processed_table(tmp_path / "store", "samples"), before)
    # and the run's leftovers (the other parameters' files) are gone
    parts = list((tmp_path / "store" / "processed" / "samples").rglob("*.parquet"))
    assert len(parts) == 2


def _two_floors(tmp_path: Path, n: int = 2) -> Path:
    traces = [p for f in ("F1", "F2")
              for p in sorted((SITE / f / "path_data_files").glob("*.txt.gz"))[:n]]
    ingest(traces, tmp_path)
    return tmp_path


def test_one_floor_then_all_gives_what_all_at_once_gives(tmp_path):
    """Calibration sessions were found and fitted over the selected walks only (and their
    subsamples drawn from one generator shared by the selection's sessions), so `--floor F1`
    followed by a full run kept other F1 results than a full run. Here an F2 walk of the same
    phone with a bias 1.9 uT off joins the F1 walk's session and moves its median."""
    f1 = sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0]
    f2 = read_trace(sorted((SITE / "F2" / "path_data_files").glob("*.txt.gz"))[0])
    f2.header.model = read_trace(f1).header.model
    xyz = ["bx", "by", "bz"]
    bias = read_trace(f1).sensors.query("stream == 'magnetic_field_uncalibrated'")[xyz].median()
    unc = f2.sensors["stream"] == "magnetic_field_uncalibrated"
    f2.sensors.loc[unc, xyz] = (bias.to_numpy() + [1.9, 0, 0]).astype("float32")
    write_trace(tmp_path / "in" / "f2.txt.gz", f2)
    for name in ("a", "b"):
        ingest([f1, tmp_path / "in" / "f2.txt.gz"], tmp_path / name)
    process_store(tmp_path / "a", floor="F1")
    report = process_store(tmp_path / "a")
    process_store(tmp_path / "b")
    cols = ["trace_id", "inputs_sha256", "session", "parts_json", "summary_json"]
    a, b = processed_catalog(tmp_path / "a")[cols], processed_catalog(tmp_path / "b")[cols]
    assert a["session"].nunique() == 1  # one session over both floors
    pd.testing.assert_frame_equal(a, b)
    # the F1 run already saw the F2 walk's bias: the full run keeps the F1 walk
    assert report.processed == ["f2"] and len(report.unchanged) == 1


def test_a_walk_with_a_missing_raw_part_fails_alone_until_reingested(tmp_path):
    """One missing raw part file stopped `process` for the whole store, and ingesting the
    file again called it unchanged."""
    store = _two_floors(tmp_path / "s", 1)
    walk = sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0]
    tid = walk.name.split(".")[0]
    part = next(store.glob(f"sensors/**/{tid}-*.parquet"))
    part.unlink()
    res = CliRunner().invoke(main, ["process", "--store", str(store)])
    assert res.exit_code == 1
    assert "processed 1, unchanged 0, skipped 0, failed 1" in res.output
    assert f"failed {tid}: {part}: missing" in res.output
    assert "Ingest their files again to repair them" in res.output
    cat = processed_catalog(store).set_index("trace_id")
    assert cat.loc[tid, "status"] == "failed"
    s = ingest([walk], store)
    assert [o.status for o in s.outcomes] == ["repaired"]
    report = process_store(store)
    assert report.processed == [tid] and not report.failed
    assert (processed_catalog(store)["status"] == "ok").all()


def test_process_cleans_temporaries_and_checks_its_files(tmp_path):
    store = _two_floors(tmp_path / "s", 1)
    process_store(store)
    folder = next((store / "processed" / "samples").rglob("*.parquet")).parent
    stale = [folder / ".tmp-999999-deadbeef-x", store / "processed" / ".tmp-999999-dead-c"]
    for p in stale:  # left by a killed run
        p.write_bytes(b"half a file")
    part = next((store / "processed" / "steps").rglob("*.parquet"))
    report = process_store(store)
    assert not any(p.exists() for p in stale) and len(report.unchanged) == 2
    # a processed file changed after it was written is refused by name, and processed again
    data = bytearray(part.read_bytes())
    data[-12] ^= 0x01  # in the footer, which page checksums do not cover; same size
    part.write_bytes(bytes(data))
    with pytest.raises(StoreError, match=f"{part.name}: processed part changed"):
        processed_table(store, "steps")
    assert len(process_store(store).processed) == 1
    assert len(processed_table(store, "steps")) > 0


def test_a_processed_catalog_of_an_older_indoormap_is_read_and_redone_when_selected(tmp_path):
    """Written before inputs_sha256 (files named by params_sha256, no part hashes): its walks
    stay readable, and `process --floor F1` redoes F1 only (it dropped F2's rows)."""
    import pyarrow.parquet as pq

    store = _two_floors(tmp_path / "s", 1)
    process_store(store)
    path = store / "processed" / "catalog.parquet"
    old = pq.read_table(path).drop_columns(["parts_json"])
    pq.write_table(old.rename_columns(["params_sha256" if c == "inputs_sha256" else c
                                       for c in old.column_names]), path)
    samples = processed_table(store, "samples")
    report = process_store(store, floor="F1")
    assert len(report.processed) == 1
    cat = processed_catalog(store)
    assert sorted(cat["floor"]) == ["F1", "F2"] and (cat["status"] == "ok").all()
    pd.testing.assert_frame_equal(processed_table(store, "samples"), samples)


def test_a_new_walk_reprocesses_only_walks_that_use_its_session_fit(tmp_path, monkeypatch):
    """The pooled session fit is an input only of walks whose calibration used it (or might):
    adding a walk to a session reprocessed every device-calibrated walk of it, byte for byte
    the same. The fit is stubbed well conditioned (hard iron = the pooled mean), as a real
    survey's rotating walks give; the sample's flat-held walks give none."""
    import dataclasses

    import numpy as np

    import survey.process_store as ps

    real_fit = ps.fit_ellipsoid
    monkeypatch.setattr(ps, "fit_ellipsoid", lambda raw: dataclasses.replace(
        real_fit(raw), status="ok", reason="", hard_iron_ut=raw.mean(axis=0),
        soft_iron=np.eye(3)))
    walks = sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))
    # the walk needing the fit: its calibrated stream and its raw one minus the phone's bias
    # are implausible (the bias, which puts it in its session, is kept)
    raw = read_trace(walks[1])
    for stream in ("magnetic_field", "magnetic_field_uncalibrated"):
        raw.sensors.loc[raw.sensors["stream"] == stream, ["x", "y", "z"]] *= 10
    write_trace(tmp_path / "in" / "needs_fit.txt.gz", raw)
    mate = walks[0]  # the same phone and session as walks[1]
    later = read_trace(mate)  # another walk of that session: the pooled fit moves
    later.sensors = later.sensors.iloc[::2].reset_index(drop=True)
    write_trace(tmp_path / "later" / "later.txt.gz", later)
    ingest([tmp_path / "in" / "needs_fit.txt.gz", mate], tmp_path / "s")
    process_store(tmp_path / "s")
    cat = processed_catalog(tmp_path / "s").set_index("trace_id")
    assert cat["session"].nunique() == 1
    assert cat.loc["needs_fit", "summary"]["calibration"] == "own-session-fit"
    ingest([tmp_path / "later" / "later.txt.gz"], tmp_path / "s")
    report = process_store(tmp_path / "s")
    assert processed_catalog(tmp_path / "s")["session"].nunique() == 1
    assert report.unchanged == [mate.name.split(".")[0]]  # device-calibrated: kept
    assert sorted(report.processed) == ["later", "needs_fit"]


def test_process_reads_the_catalogs_under_the_writer_lock(tmp_path, monkeypatch):
    """`process` read the store's and the processed catalogs before taking the writer lock:
    an ingest or another `process` committing in between was then written over with the
    stale rows (a walk shown processed whose parts the other run had replaced). Every read
    of a catalog now happens with the lock held."""
    from survey import process_store as ps
    from survey.store import SurveyStore

    walk = sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0]
    ingest([walk], tmp_path / "s")
    held = []
    real_traces, real_read = SurveyStore.traces, ps._read_processed_catalog

    def traces(self, *args, **kwargs):
        held.append((self.root / ".lock").exists())
        return real_traces(self, *args, **kwargs)

    def read(path):
        held.append((path.parent.parent / ".lock").exists())
        return real_read(path)

    monkeypatch.setattr(SurveyStore, "traces", traces)
    monkeypatch.setattr(ps, "_read_processed_catalog", read)
    process_store(tmp_path / "s")
    assert held == [True, True]
