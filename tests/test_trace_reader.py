"""Trace reader: every record type, ordering, rules, and accounting for every line."""

from __future__ import annotations

import gzip

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from survey.cli import main
from survey.errors import SurveyFormatError
from survey.trace_reader import iter_traces, parse_trace_bytes, read_trace, ReadFailure
from survey.trace_writer import render_trace, write_trace

from factories import small_trace


def _assert_same_tables(a, b):
    for name in ("sensors", "wifi", "ble", "waypoints"):
        pd.testing.assert_frame_equal(getattr(a, name).reset_index(drop=True),
                                      getattr(b, name).reset_index(drop=True), check_dtype=True)


@pytest.mark.parametrize("suffix", [".txt", ".txt.gz"])
def test_round_trip_all_record_types(tmp_path, suffix):
    trace = small_trace()
    path = write_trace(tmp_path / f"walk0001{suffix}", trace,
                       extra_lines=["1600000000123\tTYPE_BLUE\t\t16:E5:41:F6:CC:67\t-95",
                                    "1600000000124\tTYPE_BLU4\t25000\t11257\t-95"])
    got = read_trace(path)
    _assert_same_tables(trace, got)
    assert got.trace_id == "walk0001"
    h = got.header
    assert (h.site_id, h.floor_name, h.brand, h.model) == ("site_a", "F1", "ACME", "P1")
    assert h.start_ms == trace.header.start_ms and h.end_ms == trace.header.end_ms
    assert h.sensors[0].name == "Acc" and h.sensors[0].resolution == pytest.approx(0.002)
    r = got.report
    assert r.skipped == {"TYPE_BLUE": 1, "TYPE_BLU4": 1}
    assert r.bad == {} and r.accounted_lines() == r.lines_total


def test_waypoints_written_late_are_sorted_and_streams_time_ordered(tmp_path):
    trace = small_trace()
    text = render_trace(trace, waypoint_delay_ms=5000)
    lines = text.splitlines()
    # the writer mimics the real app: a waypoint line follows records with later timestamps
    wp_line = next(i for i, ln in enumerate(lines) if "TYPE_WAYPOINT" in ln)
    assert int(lines[wp_line - 1].split("\t")[0]) > int(lines[wp_line].split("\t")[0])
    # shuffle the record lines: the reader must not depend on file order
    head = [ln for ln in lines if ln.startswith("#")]
    body = [ln for ln in lines if not ln.startswith("#")]
    rng = np.random.default_rng(3)
    body = [body[i] for i in rng.permutation(len(body))]
    got = parse_trace_bytes(("\n".join(head + body) + "\n").encode(), path="shuffled.txt")
    _assert_same_tables(trace, got)
    for _, g in got.sensors.groupby("stream", observed=True):
        assert g["t_ms"].is_monotonic_increasing


def test_duplicate_bssid_in_scan_keeps_freshest_then_strongest():
    text = "\n".join([
        "100\tTYPE_WIFI\tA\t00:11:22:33:44:55\t-70\t2412\t90",
        "100\tTYPE_WIFI\tA\t00-11-22-33-44-55\t-60\t2412\t80",  # older: dropped
        "100\tTYPE_WIFI\tA\t001122334455\t-50\t2412\t90",  # same age, stronger: kept
        "100\tTYPE_WIFI\tB\tAA:BB:CC:DD:EE:FF\t-80\t5180\t70",
        "300\tTYPE_WIFI\tA\t00:11:22:33:44:55\t-65\t2412\t290",  # another scan: kept
    ]).encode()
    t = parse_trace_bytes(text)
    w = t.wifi
    assert list(w["bssid"]) == ["00:11:22:33:44:55", "aa:bb:cc:dd:ee:ff", "00:11:22:33:44:55"]
    assert list(w["rssi_dbm"]) == [-50, -80, -65]
    assert list(w["age_ms"]) == [10, 30, 10]
    assert t.report.dropped == {"duplicate_bssid_in_scan": 2}
    assert t.report.records == {"TYPE_WIFI": 5}


def test_last_seen_times_on_another_clock_give_unknown_ages():
    """Last-seen times of 0, or in microseconds since boot (Android's raw
    ``ScanResult.timestamp``), read as decades old: the maps and the localizer dropped
    every row, silently. Over 1 h before the scan, the age is unknown: taken as 0, counted,
    the row kept; a row 30 s old keeps its age."""
    t0 = 1_700_000_000_000
    text = "\n".join([
        f"{t0}\tTYPE_WIFI\tA\t00:11:22:33:44:55\t-70\t2412\t0",
        f"{t0}\tTYPE_WIFI\tB\taa:bb:cc:dd:ee:ff\t-60\t2412\t{86_400_000_000}",  # us since boot
        f"{t0}\tTYPE_WIFI\tC\taa:bb:cc:dd:ee:00\t-75\t2412\t{t0 - 30_000}",
    ]).encode()
    t = parse_trace_bytes(text)
    assert sorted(t.wifi["age_ms"]) == [0, 0, 30_000] and len(t.wifi) == 3
    assert t.report.dropped == {"wifi_last_seen_other_clock": 2}
    assert t.report.n_dropped() == 0  # kept: the store's n_dropped_rows does not count them


def test_ble_key_and_normalisation():
    line = ("5\tTYPE_BEACON\t0A1B2C3D-4E5F-4A6B-8C7D-9E0F1A2B3C4D\t10\t7\t-59\t-70\t1.5\t"
            "E0:78:A3:3D:B5:D6\t5")
    b = parse_trace_bytes(line.encode()).ble
    assert b["key"][0] == "0a1b2c3d-4e5f-4a6b-8c7d-9e0f1a2b3c4d:10:7"
    assert b["mac"][0] == "e0:78:a3:3d:b5:d6"


def test_duplicate_sensor_timestamps_keep_first():
    text = ("10\tTYPE_ACCELEROMETER\t1\t2\t3\t3\n10\tTYPE_ACCELEROMETER\t4\t5\t6\t3\n"
            "10\tTYPE_GYROSCOPE\t1\t1\t1\t3\n").encode()
    t = parse_trace_bytes(text)
    acc = t.stream("accelerometer")
    assert len(acc) == 1 and acc["x"][0] == 1
    assert len(t.stream("gyroscope")) == 1
    assert t.report.dropped == {"duplicate_timestamp": 1}


def test_a_repeated_waypoint_or_beacon_row_is_dropped_a_different_one_kept():
    beacon = "5\tTYPE_BEACON\tAB\t10\t7\t-59\t-70\t1.5\tE0:78:A3:3D:B5:D6\t5"
    text = "\n".join(["20\tTYPE_WAYPOINT\t1.5\t2", "20\tTYPE_WAYPOINT\t1.5\t3",
                      beacon, beacon.replace("-70", "-71"), "20\tTYPE_WAYPOINT\t1.5\t2",
                      beacon]).encode()
    t = parse_trace_bytes(text)
    assert t.waypoints[["x_m", "y_m"]].values.tolist() == [[1.5, 2], [1.5, 3]]
    assert list(t.ble["rssi_dbm"]) == [-70, -71]
    assert t.report.dropped == {"duplicate_waypoint": 1, "duplicate_beacon": 1}
    assert t.report.records == {"TYPE_WAYPOINT": 3, "TYPE_BEACON": 3}


BAD_LINES = [
    ("10\tTYPE_WIFI\tssid\t00:11:22:33:44:55\t-50", "field_count", "TYPE_WIFI needs 5 values, got 3"),
    ("10\tTYPE_ACCELEROMETER\t1\tabc\t3\t3", "non_numeric", "expected a number"),
    ("10\tTYPE_MAGNETIC_FIELD\t1\tNaN\t3\t3", "non_finite", "NaN"),
    ("10\tTYPE_GYROSCOPE\t1\tinf\t3\t3", "non_finite", "infinite"),
    ("x10\tTYPE_GYROSCOPE\t1\t2\t3\t3", "bad_timestamp", "timestamp"),
    ("10 TYPE_GYROSCOPE 1 2 3 3", "no_type", "no tab"),
    ("10\tgarbage\t1", "unknown_record", "not a TYPE_ name"),
    ("10\tTYPE_WIFI\tssid\tnot-a-mac\t-50\t2412\t5", "bad_bssid", "not a MAC"),
    ("10\tTYPE_WIFI\tssid\t00:11:22:33:44:55\t-500\t2412\t5", "out_of_range", "rssi"),
    # 0 dBm: a driver's "no reading", which read as the strongest signal of the walk
    ("10\tTYPE_WIFI\tssid\t00:11:22:33:44:55\t0\t2412\t5", "out_of_range", "'no reading'"),
    ("5\tTYPE_BEACON\tAB\t10\t7\t-59\t0\t1.5\tE0:78:A3:3D:B5:D6\t5", "out_of_range",
     "'no reading'"),
    # heard hours after the scan that reports it: a negative age (a damaged file gave such)
    ("10\tTYPE_WIFI\tssid\t00:11:22:33:44:55\t-50\t2412\t3600010", "out_of_range",
     "TYPE_WIFI: last-seen time more than 1000 ms after the scan"),
    ("10\tTYPE_WAYPOINT\t1.0\t\xff\xfe", "invalid_utf8", "UTF-8"),
    ("10\tTYPE_ACCELEROMETER\t1e30\t2\t3\t3", "out_of_range", "beyond +-2000 m/s^2"),
    ("10\tTYPE_MAGNETIC_FIELD_UNCALIBRATED\t1\t2\t3\t4\t5\t-2e4\t3", "out_of_range",
     "TYPE_MAGNETIC_FIELD_UNCALIBRATED: a value beyond +-10000 uT"),
    ("10\tTYPE_ROTATION_VECTOR\t0.1\t2\t0.3\t3", "out_of_range", "beyond +-1.5"),
    # finite: it crashed `process` for every walk of the store (1e155 m)
    ("10\tTYPE_WAYPOINT\t1e155\t4.4", "out_of_range", "TYPE_WAYPOINT: a coordinate beyond"),
]


@pytest.mark.parametrize("line,reason,hint", BAD_LINES)
def test_bad_line_lenient_skips_and_counts(line, reason, hint):
    good = "5\tTYPE_ACCELEROMETER\t1\t2\t3\t3"
    data = ("#\tstartTime:1\n" + good + "\n").encode() + line.encode("latin-1") + b"\n" + \
        good.replace("5", "7", 1).encode() + b"\n"
    t = parse_trace_bytes(data, path="walk.txt")
    r = t.report
    assert r.bad == {reason: 1}
    assert r.accounted_lines() == r.lines_total == 4
    assert len(t.stream("accelerometer")) == 2
    assert r.messages[0].startswith("walk.txt:3: ") and hint in r.messages[0]


@pytest.mark.parametrize("line,reason,hint", BAD_LINES)
def test_bad_line_strict_raises_with_file_and_line(line, reason, hint):
    data = b"5\tTYPE_ACCELEROMETER\t1\t2\t3\t3\n" + line.encode("latin-1") + b"\n"
    with pytest.raises(SurveyFormatError) as info:
        parse_trace_bytes(data, path="walk.txt", strict=True)
    assert str(info.value).startswith("walk.txt:2: ")
    assert hint in str(info.value) and info.value.reason == reason and info.value.line == 2


@pytest.mark.parametrize("x, accuracy", [
    ("1", "1_0"), ("1", "\u0663"), ("1", "+3"), ("1", "\uff13"),   # integers
    ("1_0.5", "3"), ("\u0661.\u0665", "3"), ("\x0c1.5", "3"), ("\uff11", "3"),  # floats
])
def test_number_spellings_only_python_takes_are_bad_lines(x, accuracy):
    """'_' grouping, non-ASCII digits, '+' on an integer and white space other than spaces
    are numbers to Python's int()/float() but not to the format (nor to pyarrow's parser, the
    fast path): a line holding one is a ``non_numeric`` bad line whichever path reads it."""
    good = "5\tTYPE_ACCELEROMETER\t1\t2\t3\t3"
    line = f"10\tTYPE_ACCELEROMETER\t{x}\t2\t3\t{accuracy}"
    t = parse_trace_bytes(f"{good}\n{line}\n".encode(), path="walk.txt")
    assert t.report.bad == {"non_numeric": 1} and len(t.stream("accelerometer")) == 1
    with pytest.raises(SurveyFormatError, match="walk.txt:2: .*expected"):
        parse_trace_bytes(f"{good}\n{line}\n".encode(), path="walk.txt", strict=True)


def test_nan_with_a_payload_is_non_finite_on_both_paths():
    """``nan(...)`` may hold '_' (pyarrow takes ``nan(a_b)``): the fallback, forced by a line
    pyarrow refuses ('+3'), must call it ``non_finite`` as the fast path does."""
    good = "5\tTYPE_ACCELEROMETER\t1\t2\t3\t3\n"
    nan = "10\tTYPE_ACCELEROMETER\tnan(a_b)\t2\t3\t3\n"
    plus = "20\tTYPE_ACCELEROMETER\t1\t2\t3\t+3\n"
    assert parse_trace_bytes((good + nan).encode()).report.bad == {"non_finite": 1}
    assert parse_trace_bytes((good + nan + plus).encode()).report.bad == \
        {"non_finite": 1, "non_numeric": 1}


def test_empty_file(tmp_path):
    t = parse_trace_bytes(b"")
    assert t.report.lines_total == 0 and len(t.sensors) == 0 and len(t.waypoints) == 0
    assert list(t.sensors.columns)[:2] == ["stream", "t_ms"] and t.is_empty
    p = tmp_path / "empty.txt"
    p.write_bytes(b"")
    with pytest.raises(SurveyFormatError, match=r"empty\.txt: no sensor sample, waypoint or "
                       r"scan in 0 lines \(0 bad\): empty, or not a trace file") as ei:
        read_trace(p)
    assert ei.value.reason == "empty"


def test_a_file_of_another_kind_or_a_folder_is_refused_naming_it(tmp_path):
    """A floor's JSON files and its folder are what a user passes by mistake: each is refused
    naming the path and saying what it is, not read as an empty walk or called a FIFO."""
    info = tmp_path / "floor_info.json"
    info.write_text('{"map_info": {"width": 250.2, "height": 200.1}}\n')
    with pytest.raises(SurveyFormatError, match=r"floor_info\.json: no sensor sample.* in 1 "
                       r"lines \(1 bad\): empty, or not a trace file \(first problem"):
        read_trace(info)
    with pytest.raises(SurveyFormatError, match=rf"{tmp_path}: a folder, not a trace file"):
        read_trace(tmp_path)


@pytest.mark.parametrize("n_waypoints", [0, 1])
def test_no_or_one_waypoint_parses(n_waypoints):
    trace = small_trace()
    trace.waypoints = trace.waypoints.iloc[:n_waypoints]
    t = parse_trace_bytes(render_trace(trace).encode())
    assert len(t.waypoints) == n_waypoints and len(t.sensors) == len(trace.sensors)


def test_truncated_gzip(tmp_path):
    path = write_trace(tmp_path / "walk.txt.gz", small_trace(n=400))
    full = read_trace(path)
    data = path.read_bytes()
    cut = tmp_path / "cut.txt.gz"
    cut.write_bytes(data[: len(data) * 2 // 3])
    t = read_trace(cut)  # lenient: keeps what is readable, counts the cut line
    assert 0 < len(t.sensors) < len(full.sensors)
    assert t.report.bad.get("truncated", 0) <= 1
    assert "truncated gzip stream" in t.report.messages[0]
    assert t.report.accounted_lines() == t.report.lines_total
    with pytest.raises(SurveyFormatError, match="cut.txt.gz: truncated gzip"):
        read_trace(cut, strict=True)


def test_a_gzip_stream_damaged_inside_is_refused_whole(tmp_path):
    """One flipped byte inside the deflate data: inflating goes on with garbage (rows with
    mixed-up BSSIDs and times) for a while before it fails, or with one wrong value that only
    the checksum catches, so no prefix can be trusted. Both modes refuse the file, naming it;
    a lenient ingest reports it failed and stores nothing."""
    from survey.store import SurveyStore

    path = write_trace(tmp_path / "walk.txt.gz", small_trace(n=2000))
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x10
    bad = tmp_path / "flip.txt.gz"
    bad.write_bytes(bytes(data))
    for strict in (False, True):
        with pytest.raises(SurveyFormatError, match=r"flip.txt.gz: damaged gzip stream \("):
            read_trace(bad, strict=strict)
    res = CliRunner().invoke(main, ["ingest", str(bad), "--store", str(tmp_path / "store")])
    assert res.exit_code == 1 and "flip.txt.gz" in res.output and "damaged gzip" in res.output
    store = tmp_path / "store"
    assert not store.exists() or len(SurveyStore.open(store).catalog()) == 0


def test_random_bytes(tmp_path):
    rng = np.random.default_rng(0)
    p = tmp_path / "noise.txt"
    p.write_bytes(rng.integers(0, 256, 20000, dtype=np.uint8).tobytes())
    t = parse_trace_bytes(p.read_bytes(), path=str(p))
    assert t.report.accounted_lines() == t.report.lines_total
    assert len(t.sensors) == 0
    with pytest.raises(SurveyFormatError, match="noise.txt: no sensor sample, waypoint or scan"):
        read_trace(p)
    with pytest.raises(SurveyFormatError, match="noise.txt:1"):
        read_trace(p, strict=True)
    gz = tmp_path / "noise.txt.gz"
    gz.write_bytes(b"\x1f\x8b" + rng.integers(0, 256, 2000, dtype=np.uint8).tobytes())
    for strict in (False, True):  # not a gzip stream that was cut short: nothing to keep
        with pytest.raises(SurveyFormatError, match="noise.txt.gz: damaged gzip stream"):
            read_trace(gz, strict=strict)


def test_missing_file_and_size_limit(tmp_path):
    with pytest.raises(SurveyFormatError, match="cannot read"):
        read_trace(tmp_path / "nope.txt")
    p = tmp_path / "big.txt.gz"
    p.write_bytes(gzip.compress(b"1\tTYPE_WAYPOINT\t1\t2\n" * 1000))
    with pytest.raises(SurveyFormatError, match="refused"):
        read_trace(p, max_bytes=1000)


def test_iter_traces_batches_match_single_reads(tmp_path):
    paths = [write_trace(tmp_path / f"w{i}.txt.gz", small_trace(n=60 + i, seed=i,
                                                                  trace_id=f"w{i}"))
             for i in range(5)]
    (tmp_path / "unreadable.txt").mkdir()
    items = list(iter_traces([*paths, tmp_path / "unreadable.txt"], batch_bytes=8000))
    assert isinstance(items[-1], ReadFailure)
    for p, t in zip(paths, items[:-1]):
        single = read_trace(p)
        _assert_same_tables(single, t)
        assert single.report == t.report


def test_iter_traces_strict_reports_the_first_problem_in_path_order(tmp_path):
    """Batches are prepared one ahead; in strict mode the earlier files still come first."""
    good = [write_trace(tmp_path / f"a{i}.txt", small_trace(n=40, seed=i, trace_id=f"a{i}"))
            for i in range(3)]
    big = tmp_path / "z_big.txt"
    big.write_bytes(b"1\tTYPE_WAYPOINT\t1\t2\n" * 5000)
    cap = max(p.stat().st_size for p in good) + 1
    seen = []
    with pytest.raises(SurveyFormatError, match="z_big.txt.*limit"):
        for t in iter_traces([*good, big], strict=True, batch_bytes=1, max_bytes=cap):
            seen.append(t.trace_id)
    assert seen == ["a0", "a1", "a2"]
    bad = tmp_path / "a1.txt"
    bad.write_text(bad.read_text() + "5\tTYPE_WAYPOINT\tx\t2\n")
    with pytest.raises(SurveyFormatError, match="a1.txt:.*expected a number"):
        list(iter_traces([*good, big], strict=True, batch_bytes=1, max_bytes=cap * 2))


def test_real_floor_every_line_accounted(ilc_floor):
    """Store-independent check on the real traces: our counts per record type equal a plain
    count of the lines, and no line is unaccounted for."""
    files = sorted((ilc_floor / "path_data_files").glob("*.txt.gz"))
    for item in iter_traces(files):
        counts: dict[str, int] = {}
        n = 0
        with gzip.open(item.report.path, "rt", encoding="utf-8") as fh:
            for line in fh:
                n += 1
                parts = line.rstrip("\n").split("\t")
                key = "#" if line.startswith("#") else parts[1]
                counts[key] = counts.get(key, 0) + 1
        r = item.report
        assert r.lines_total == n and r.accounted_lines() == n
        assert r.header_lines == counts.pop("#")
        assert r.bad == {}
        documented = {k: v for k, v in counts.items() if k in r.records}
        assert documented == r.records
        assert {k: v for k, v in counts.items() if k not in r.records} == r.skipped
        assert len(item.sensors) == sum(v for k, v in r.records.items()
                                        if k not in ("TYPE_WIFI", "TYPE_BEACON", "TYPE_WAYPOINT"))
        assert len(item.wifi) + r.dropped.get("duplicate_bssid_in_scan", 0) == r.records.get(
            "TYPE_WIFI", 0)


def test_byte_order_mark_and_zero_padding_lose_nothing_and_a_bad_checksum_is_refused(
        tmp_path):
    """A UTF-8 BOM before the header and zero bytes after a complete gzip stream keep every
    line; a checksum that does not match the text is refused in both modes, as the text
    (or the checksum: which one cannot be told) is not what was written."""
    trace = small_trace(n=400)
    text = render_trace(trace).encode()
    full = parse_trace_bytes(text)
    bom = parse_trace_bytes(b"\xef\xbb\xbf" + text)
    assert bom.report.bad == {} and bom.header == full.header
    _assert_same_tables(bom, full)
    packed = gzip.compress(text, mtime=0)
    (tmp_path / "pad.txt.gz").write_bytes(packed + bytes(16))
    padded = read_trace(tmp_path / "pad.txt.gz", strict=True)
    _assert_same_tables(padded, full)
    crc = bytearray(packed)
    crc[-5] ^= 0xFF   # the CRC-32 in the trailer
    (tmp_path / "crc.txt.gz").write_bytes(bytes(crc))
    for strict in (False, True):
        with pytest.raises(SurveyFormatError, match=r"crc.txt.gz: damaged gzip stream \(.*"
                                                    "(?i:checksum|data check)"):
            read_trace(tmp_path / "crc.txt.gz", strict=strict)
