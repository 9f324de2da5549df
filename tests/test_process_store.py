"""`indoormap process` / `survey-report` over a store: results kept, skips explained."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
from click.testing import CliRunner

from survey.cli import main
from survey.cli_process import plan_floor_name
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
    wifi = processed_table(tmp_path / "store", "wifi")
    assert {"x_m", "y_m", "bssid", "rssi_dbm", "age_ms"} <= set(wifi.columns)
    again = runner.invoke(main, ["process", "--store", str(tmp_path / "store")])
    assert "processed 0, unchanged 3, skipped 0" in again.output  # nothing changed: no work
    assert "calibration: 1 device-calibrated, 1 not-calibrated" in again.output
    report = runner.invoke(main, ["survey-report", "--store", str(tmp_path / "store"),
                                  "--csv", str(tmp_path / "qa.csv")])
    assert report.exit_code == 0, report.output
    assert "device-calibrated" in report.output and "flagged legs by reason" in report.output
    assert (tmp_path / "qa.csv").read_text().startswith("trace_id,floor,status,steps")
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
