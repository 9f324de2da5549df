"""`indoormap process` / `survey-report` over a store: results kept, skips explained."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from survey.cli import main
from survey.ingest import ingest
from survey.process_store import processed_catalog, processed_table
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
    ingest([*traces[:2], tmp_path / "in"], tmp_path / "store")
    runner = CliRunner()
    res = runner.invoke(main, ["process", "--store", str(tmp_path / "store"),
                               "--floor-plan", str(floor)])
    assert res.exit_code == 0, res.output
    assert "processed 2, unchanged 0, skipped 1" in res.output
    assert "skipped single: a walk needs at least two waypoints" in res.output
    assert "ill-conditioned" in res.output  # flat-held sessions: our own fit is not applied
    cat = processed_catalog(tmp_path / "store")
    assert sorted(cat["status"]) == ["ok", "ok", "skipped"]
    samples = processed_table(tmp_path / "store", "samples", floor="F1")
    assert samples["trace_id"].nunique() == 2 and samples[["x_m", "y_m"]].notna().all().all()
    wifi = processed_table(tmp_path / "store", "wifi")
    assert {"x_m", "y_m", "bssid", "rssi_dbm", "age_ms"} <= set(wifi.columns)
    again = runner.invoke(main, ["process", "--store", str(tmp_path / "store")])
    assert "processed 0, unchanged 3, skipped 0" in again.output  # nothing changed: no work
    report = runner.invoke(main, ["survey-report", "--store", str(tmp_path / "store"),
                                  "--csv", str(tmp_path / "qa.csv")])
    assert report.exit_code == 0, report.output
    assert "device-calibrated" in report.output and "flagged legs by reason" in report.output
    assert (tmp_path / "qa.csv").read_text().startswith("trace_id,floor,status,steps")
    for command in ("process", "survey-report"):  # a floor the store does not hold
        res = runner.invoke(main, [command, "--store", str(tmp_path / "store"), "--floor", "F9"])
        assert res.exit_code == 2 and "no walks for floor F9; the store has" in res.output
        assert "/F1 (site/floor)" in res.output


def test_process_without_processing_says_so(tmp_path):
    ingest([sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0]], tmp_path / "s")
    res = CliRunner().invoke(main, ["survey-report", "--store", str(tmp_path / "s")])
    assert res.exit_code == 1 and "not processed yet" in res.output
