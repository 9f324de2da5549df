"""Wi-Fi and BLE logs in indoormap's walk-line format (``wifi_log``, ``ble_log``): read with
the trace reader's checks, into the same store tables, so that the same walks give the same
maps and fingerprints in either format."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from radio_fixtures import built  # noqa: F401  (fixture)

from survey.cli import main
from survey.errors import SurveyFormatError
from survey.ingest import ingest
from survey.store import SurveyStore
from survey.trace_format import ParseReport
from survey.trace_reader import read_trace
from survey.walkline import plan_walks, read_walk_plan
from survey.walkline_radio import parse_ble_csv, parse_wifi_csv
from survey.walkline_writer import write_walk_plan

SITE = Path(__file__).resolve().parents[1] / "data" / "sample_site"
T0 = 1_700_000_000_000  # the walks' time (Unix ms)


def _traces(floor: str = "F1"):
    return [read_trace(p) for p in sorted((SITE / floor / "path_data_files").glob("*.txt.gz"))]


def test_simulated_walks_read_the_same_as_traces_and_as_walk_lines(tmp_path):
    """Every table of every sample walk (sensors, Wi-Fi, BLE, waypoints) comes back equal,
    dtypes included, from its walk-line plan and logs; every line of the logs is counted."""
    traces = _traces()
    assert sum(len(t.wifi) for t in traces) > 1000 and sum(len(t.ble) for t in traces) > 100
    assert any(not len(t.wifi) for t in traces)  # a walk without Wi-Fi: no Wi-Fi log
    walks = read_walk_plan(write_walk_plan(tmp_path / "plan", traces))
    for trace, (back, _, _) in zip(traces, walks):
        for table in ("sensors", "wifi", "ble", "waypoints"):
            pd.testing.assert_frame_equal(getattr(back, table), getattr(trace, table))
        r = back.report
        assert r.accounted_lines() == r.lines_total and not r.bad
        assert r.records.get("WIFI_ROW", 0) == len(trace.wifi)
        assert r.records["BLE_ROW"] == len(trace.ble)


def test_a_floor_built_from_walk_lines_has_the_traces_maps_and_fingerprints(tmp_path):
    """The sample's F1 walks as traces and as a walk-line plan: every raster and radio table
    of the two bundles is byte for byte the same (only the source walks' table differs: other
    files, other hashes), and a walk-line walk is localized from its first Wi-Fi fix."""
    plan = write_walk_plan(tmp_path / "walklines", _traces())
    runner = CliRunner()
    for args in (["build", str(SITE / "F1"), "-o", str(tmp_path / "traces")],
                 ["build", str(plan.parent), "--plan", str(SITE / "F1" / "geojson_map.json"),
                  "-o", str(tmp_path / "lines")]):
        result = runner.invoke(main, args)
        assert result.exit_code == 0, result.output
    a, b = tmp_path / "traces" / "F1", tmp_path / "lines" / "F1"
    members = sorted(p.relative_to(a) for p in a.rglob("*") if p.suffix in (".npy", ".parquet"))
    assert len(members) > 15 and Path("tables/wifi_fp.parquet") in members
    differ = [str(m) for m in members if (a / m).read_bytes() != (b / m).read_bytes()]
    assert differ == ["tables/source_walks.parquet"]
    first = plan_walks(plan)[0].walk_id
    result = runner.invoke(main, ["localize", str(tmp_path / "lines"), str(plan),
                                  "-o", str(tmp_path / "loc"), "--no-plot"])
    assert result.exit_code == 0, result.output
    assert re.search(rf"{first}: \d+ steps .* start first Wi-Fi fix", result.output)
    # wifi-locate and floor take the plan's walks too (they left plans out: no scans), and
    # print for them what they print for the trace files
    for command in (["wifi-locate", str(b)], ["floor", str(tmp_path / "lines" / "_site")]):
        csv, status = {}, {}
        for name, walks in (("traces", str(SITE / "F1" / "path_data_files")),
                            ("lines", str(plan))):
            result = runner.invoke(main, [*command, walks])
            csv[name], status[name] = sorted(result.stdout.splitlines()), result.exit_code
        # (floor: the walk without Wi-Fi has no floor on a site of one floor, either way)
        assert len(csv["lines"]) > 100 and csv["lines"] == csv["traces"]
        assert status["lines"] == status["traces"] == (command[0] == "floor")


def _wifi(rows: list[str], header: str = "t_ms,bssid,rssi_dbm,freq_mhz,ssid,last_seen_ms",
          strict: bool = False) -> tuple[pd.DataFrame, ParseReport]:
    report = ParseReport(path="w.csv")
    data = "\n".join([header, *rows]).encode() + b"\n"
    return parse_wifi_csv(data, reference_ms=T0, report=report, path="w.csv",
                          strict=strict), report


def test_wifi_log_rows_are_read_as_the_trace_reader_reads_scans():
    """BSSIDs in any MAC spelling become aa:bb:..; RSSI rounds to whole dBm; a scan listing
    a BSSID twice keeps its freshest row; an SSID of digits stays text; absent frequency and
    last-seen time are 0 (unknown) and the scan time (age 0)."""
    wifi, report = _wifi([
        f"{T0 + 2000},AA-BB-CC-00-00-01,-60.6,5180,007,{T0 + 1500}",
        f"{T0 + 2000},aabbcc000001,-50,5180,007,{T0 + 1000}",  # staler: dropped
        f"{T0 + 2000},aa:bb:cc:00:00:02,-70,,\"a,b\",",
        f"{T0},AA:BB:CC:00:00:03,-80,2412,,{T0}",
    ])
    assert wifi["bssid"].tolist() == ["aa:bb:cc:00:00:03", "aa:bb:cc:00:00:01",
                                      "aa:bb:cc:00:00:02"]
    assert wifi["rssi_dbm"].tolist() == [-80, -61, -70]
    assert wifi["ssid"].tolist() == ["", "007", "a,b"]
    assert wifi["freq_mhz"].tolist() == [2412, 5180, 0]
    assert wifi["age_ms"].tolist() == [0, 500, 0]
    assert wifi.dtypes.astype(str).to_dict() == {
        "scan_t_ms": "int64", "ssid": "str", "bssid": "str", "rssi_dbm": "int16",
        "freq_mhz": "int32", "last_seen_ms": "int64", "age_ms": "int64"}
    assert report.dropped == {"duplicate_bssid_in_scan": 1}
    assert report.records == {"WIFI_ROW": 4} and report.accounted_lines() == report.lines_total
    only_required, _ = _wifi([f"{T0},aa:bb:cc:00:00:01,-60"], header="t_ms,bssid,rssi_dbm")
    assert only_required[["freq_mhz", "age_ms", "ssid"]].values.tolist() == [[0, 0, ""]]
    # a frequency of 0, what the store keeps for an unknown one, reads back as unknown
    zero, report = _wifi([f"{T0},aa:bb:cc:00:00:01,-60,0,x,{T0}"])
    assert zero["freq_mhz"].tolist() == [0] and not report.bad


BAD_WIFI = [  # (row, reason, what its message says)
    (f"{T0},not-a-mac,-60,2412,x,{T0}", "bad_bssid", "column bssid ('not-a-mac')"),
    (f"{T0},aa:bb:cc:00:00:01,5,2412,x,{T0}", "out_of_range", "column rssi_dbm (5)"),
    (f"{T0},aa:bb:cc:00:00:01,abc,2412,x,{T0}", "non_numeric", "column rssi_dbm ('abc')"),
    (f"{T0},aa:bb:cc:00:00:01,,2412,x,{T0}", "non_numeric", "column rssi_dbm (empty)"),
    (f"{T0}.5,aa:bb:cc:00:00:01,-60,2412,x,{T0}", "non_numeric", "column t_ms"),
    (f"{T0},aa:bb:cc:00:00:01,-60,2412000,x,{T0}", "out_of_range", "column freq_mhz (2412000)"),
    (f"{T0},aa:bb:cc:00:00:01,-60,2412,x,{T0 + 5000}", "out_of_range", "column last_seen_ms"),
    (f"{T0},aa:bb:cc:00:00:01,-60,2412,x,-1e30", "out_of_range", "column last_seen_ms"),
    (f"{T0 + 13 * 3_600_000},aa:bb:cc:00:00:01,-60,2412,x,", "time_outlier", "column t_ms"),
    (f"{T0},aa:bb:cc:00:00:01,-60", "field_count", "3 fields, the header has 6"),
]


@pytest.mark.parametrize("row,reason,said", BAD_WIFI, ids=[r for _, r, _ in BAD_WIFI])
def test_a_bad_wifi_row_is_counted_naming_its_line_and_column_or_refused_in_strict_mode(
        row, reason, said):
    good = f"{T0 + 1000},aa:bb:cc:00:00:09,-65,2412,x,{T0 + 1000}"
    wifi, report = _wifi([good, row, good.replace(":09", ":08")])
    assert len(wifi) == 2 and report.bad == {reason: 1}
    assert report.messages[0].startswith("w.csv:3: ") and said in report.messages[0]
    assert report.accounted_lines() == report.lines_total
    with pytest.raises(SurveyFormatError, match=re.escape(said)) as err:
        _wifi([good, row], strict=True)
    assert err.value.line == 3 and err.value.reason == reason


def test_ble_log_rows_are_read_as_the_trace_reader_reads_beacons():
    report = ParseReport(path="b.csv")
    uuid = "FDA50693-A4E2-4FB1-AFCF-C6EB07647825"
    data = "\n".join([
        "t_ms,uuid,major,minor,rssi_dbm",
        f"{T0 + 500},{uuid},10,3,-71.2",
        f"{T0},{uuid},10,2,-80",
        f"{T0},{uuid},10,2,-80",  # the same row twice: dropped
        f"{T0},{uuid},70000,2,-80",  # major out of range
        f"{T0},,10,2,-80",  # no uuid
    ]).encode()
    late = b"t_ms,uuid,major,minor,rssi_dbm,last_seen_ms\n" \
        + f"{T0},{uuid},10,2,-80,1e20\n{T0},{uuid},10,3,-80,{T0}\n".encode()
    with pytest.raises(SurveyFormatError, match="outside .* column last_seen_ms"):
        parse_ble_csv(late, reference_ms=T0, report=ParseReport(), path="b.csv", strict=True)
    ble = parse_ble_csv(data, reference_ms=T0, report=report, path="b.csv")
    assert ble["key"].tolist() == [f"{uuid.lower()}:10:2", f"{uuid.lower()}:10:3"]
    assert ble["rssi_dbm"].tolist() == [-80, -71] and ble["t_ms"].tolist() == [T0, T0 + 500]
    assert ble["tx_power_dbm"].tolist() == [0, 0] and ble["mac"].tolist() == ["", ""]
    assert ble["distance_m"].isna().all() and (ble["last_seen_ms"] == ble["t_ms"]).all()
    assert report.dropped == {"duplicate_beacon": 1}
    assert report.bad == {"out_of_range": 1, "non_numeric": 1}
    assert "b.csv:5: major/minor outside [0, 65535] or absurd tx power: column major (70000)" \
        in report.messages
    assert "b.csv:6: non-numeric, missing or non-finite value: column uuid (empty)" \
        in report.messages


@pytest.mark.parametrize("text,match,reason", [
    ("t_ms,rssi_dbm\n1,-60\n", "Wi-Fi log needs a 'bssid' column", "csv"),
    ("t_ms;bssid;rssi_dbm\n1;aa:bb:cc:00:00:01;-60\n", "comma-separated, not ';'", "csv"),
    (f"t_ms,bssid,rssi_dbm\n{T0},x,-60\n{T0},aa:bb:cc:00:00:01,9\n",
     r"w.csv: Wi-Fi log has no usable row: none of its 2 rows is usable \(bad_bssid 1, "
     r"out_of_range 1; the first: w.csv:2: bssid is not a MAC address: column bssid", "empty"),
    ("t_ms,bssid,rssi_dbm\n1000,aa:bb:cc:00:00:01,-60\n", "the log is on another clock",
     "clock"),
    (f"t_ms,bssid,rssi_dbm\n{T0 // 1000},aa:bb:cc:00:00:01,-60\n", "the log in seconds",
     "clock"),
])
def test_a_wifi_log_that_cannot_be_read_is_refused_naming_it(text, match, reason):
    with pytest.raises(SurveyFormatError, match=match) as err:
        parse_wifi_csv(text.encode(), reference_ms=T0, report=ParseReport(), path="w.csv")
    assert err.value.reason == reason


def test_a_site_of_floor_folders_holding_walk_plans_builds(built, tmp_path):  # noqa: F811
    """A site whose floor folders hold their plan and a walk-line survey (no
    path_data_files/): ``build SITE`` said "F1/path_data_files: no such file or folder".
    It reads each floor folder's walk plans, and builds the maps the traces build."""
    import shutil

    for floor in ("F1", "F2"):
        (tmp_path / "site" / floor).mkdir(parents=True)
        for name in ("geojson_map.json", "floor_info.json", "planned_routes.geojson"):
            shutil.copy(SITE / floor / name, tmp_path / "site" / floor / name)
        write_walk_plan(tmp_path / "site" / floor / "survey", _traces(floor))
    result = CliRunner().invoke(main, ["build", str(tmp_path / "site"), "-o",
                                       str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    for floor in ("F1", "F2"):
        a, b = built / floor, tmp_path / "out" / floor
        layers = sorted(p.relative_to(a) for p in a.rglob("*.npy"))
        assert len(layers) > 10
        assert [m for m in layers if (a / m).read_bytes() != (b / m).read_bytes()] == []


def test_a_header_only_radio_log_is_a_walk_that_heard_nothing():
    report = ParseReport()
    assert parse_wifi_csv(b"t_ms,bssid,rssi_dbm\n", reference_ms=T0, report=report).empty
    assert report.records == {"WIFI_ROW": 0} and report.lines_total == 1


def _plan(folder: Path, traces, **overrides) -> Path:
    plan = write_walk_plan(folder, traces)
    data = json.loads(plan.read_text())
    for k, v in overrides.items():
        data["features"][0]["properties"][k] = v
    plan.write_text(json.dumps(data))
    return plan


def test_ingest_stores_a_walks_radio_logs_and_sees_them_change(tmp_path):
    traces = _traces()[:2]
    plan = _plan(tmp_path / "p", traces)
    store = tmp_path / "store"
    assert ingest([plan], store).status_counts() == {"new": 2}
    wifi = SurveyStore.open(store).table("wifi", trace_ids=traces[0].trace_id)
    assert len(wifi) == len(traces[0].wifi) > 0
    assert ingest([plan], store).status_counts() == {"unchanged": 2}
    log = plan.parent / "logs" / f"{traces[0].trace_id}.wifi.csv"
    log.write_bytes(log.read_bytes().replace(b",-6", b",-7", 1))  # one RSSI 10 dB lower
    assert ingest([plan], store).status_counts() == {"changed": 1, "unchanged": 1}


def test_a_missing_radio_log_fails_its_walk_alone_and_a_log_that_is_no_path_the_plan(
        tmp_path):
    traces = _traces()[:2]
    plan = _plan(tmp_path / "p", traces, ble_log="logs/gone.csv")
    summary = ingest([plan], tmp_path / "store")
    assert summary.status_counts() == {"new": 1, "failed": 1}
    assert "BLE log 'logs/gone.csv' not readable" in summary.failed[0].detail
    plan = _plan(tmp_path / "q", traces, wifi_log=5)
    with pytest.raises(SurveyFormatError, match="'wifi_log' must be a path"):
        plan_walks(plan)


def test_the_writer_names_logs_by_safe_names(tmp_path):
    trace = _traces()[0]
    trace.trace_id = "../../outside"
    plan = write_walk_plan(tmp_path / "p", [trace])
    written = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*.csv"))
    assert len(written) == 3 and all(p.startswith("p/logs/_._.._outside-") for p in written)
    assert read_walk_plan(plan)[0][0].trace_id == "../../outside"


def test_a_walk_without_radio_logs_keeps_the_identity_it_had(tmp_path):
    """A store ingested before radio logs existed must not see its walks as changed."""
    trace = _traces()[0]
    trace.wifi, trace.ble = trace.wifi.iloc[:0], trace.ble.iloc[:0]
    plan = write_walk_plan(tmp_path / "p", [trace])
    walk = plan_walks(plan)[0]
    logs = walk.log_bytes()
    assert set(logs.files) == {"sensor_log"}
    feature = {**walk.feature, "properties": walk.props}
    assert walk.identity(logs) == (json.dumps(feature, sort_keys=True).encode() + b"\n"
                                   + logs.files["sensor_log"][1])
    assert np.array_equal(walk.parse(logs).waypoints["x_m"], trace.waypoints["x_m"])


def test_a_plan_whose_logs_lie_outside_its_folder_builds_from_that_folder(tmp_path):
    """``build survey/plans --plan ...`` of a plan naming ``../logs/x.csv``: ingest read
    every walk, and build found none of them "from" the folder (it looked where the logs
    were), so it said "no readable walks" (or, with --floor, "every processed walk is
    excluded")."""
    survey = tmp_path / "survey"
    plan = write_walk_plan(survey, _traces())
    (survey / "plans").mkdir()
    data = json.loads(plan.read_text())
    for f in data["features"]:
        for prop in ("sensor_log", "wifi_log", "ble_log"):
            if prop in f["properties"]:
                f["properties"][prop] = "../" + f["properties"][prop]
    (survey / "plans" / "F1.geojson").write_text(json.dumps(data))
    plan.unlink()
    result = CliRunner().invoke(main, ["build", str(survey / "plans"), "--plan",
                                       str(SITE / "F1" / "geojson_map.json"),
                                       "-o", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert "F1: 6 walks" in result.output


def test_a_site_whose_floors_are_named_with_spaces_builds_and_localizes(tmp_path):
    """Walks recording floor "Level 1" in a floor folder "Level 1": the site build refused
    the folder ("its walks are recorded as floor Level_1, not Level 1"), and renamed, the
    bundles of Level_1 did not take a walk naming "Level 1" ("the walk names no floor")."""
    import shutil

    site = tmp_path / "site"
    for floor, name in (("F1", "Level 1"), ("F2", "Level 2")):
        (site / name).mkdir(parents=True)
        for f in ("floor_info.json", "geojson_map.json"):
            shutil.copy(SITE / floor / f, site / name / f)
        traces = _traces(floor)[:3]
        for t in traces:
            t.header.floor_name, t.header.floor_id = name, None
        write_walk_plan(site / name / "path_data_files", traces)
    runner = CliRunner()
    built = runner.invoke(main, ["build", str(site), "-o", str(tmp_path / "out")])
    assert built.exit_code == 0, built.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["Level_1", "Level_2",
                                                                    "_site"]
    result = runner.invoke(main, ["localize", str(tmp_path / "out"),
                                  str(site / "Level 2" / "path_data_files"), "-o",
                                  str(tmp_path / "loc"), "--no-plot"])
    assert result.exit_code == 0, result.output
    assert result.output.count("(Level_2) by auto") == 3
    floors = runner.invoke(main, ["floor", str(tmp_path / "out" / "_site"),
                                  str(site / "Level 2" / "path_data_files")])
    assert floors.exit_code == 0, floors.output
    assert "100.00 % on the floor the trace files name" in floors.output
