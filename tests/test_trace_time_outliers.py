"""A row whose time is far from its walk's other rows of its type (a wrong clock, a stray row).

One accelerometer row at time 0 among rows of 2019 made step detection ask for 625 GiB (a
uniform time grid over the stream's span) and crashed `build`, `process` and `localize`; a
waypoint at time 0 silently degraded the map. Such a row is now a ``time_outlier`` bad line
(skipped and counted, or refused in strict mode), while a whole stream stamped with another
clock is still read and reported by ``Trace.clock_mismatch``. Step detection refuses a span
that no walk has with a ProcessingError rather than running out of memory."""

from __future__ import annotations

import numpy as np
import pytest

from survey.errors import ProcessingError, SurveyFormatError
from survey.steps import detect_steps
from survey.trace_format import MAX_FROM_MEDIAN_TIME_MS, far_from_median_time
from survey.trace_reader import iter_traces, parse_trace_bytes
from survey.trace_writer import render_trace

from factories import small_trace


def _text(extra: str = "", shift_wifi_ms: int = 0) -> bytes:
    trace = small_trace(n=200)
    if shift_wifi_ms:
        trace.wifi["scan_t_ms"] += shift_wifi_ms
        trace.wifi["last_seen_ms"] += shift_wifi_ms
    return render_trace(trace).encode() + extra.encode()


STRAY = ("0\tTYPE_ACCELEROMETER\t1\t2\t3\t3\n"
         "10000000000000\tTYPE_WAYPOINT\t5\t5\n")  # time 0, and the year 2286


def test_stray_rows_far_in_time_are_skipped_counted_and_named():
    clean = parse_trace_bytes(_text(), path="walk.txt")
    t = parse_trace_bytes(_text(STRAY), path="walk.txt")
    r = t.report
    assert r.bad == {"time_outlier": 2} and r.accounted_lines() == r.lines_total
    n = clean.report.lines_total
    assert r.messages[0].startswith(f"walk.txt:{n + 1}: TYPE_ACCELEROMETER: time 0 ms is over")
    assert r.messages[1].startswith(f"walk.txt:{n + 2}: TYPE_WAYPOINT: time 10000000000000 ms")
    for name in ("sensors", "wifi", "ble", "waypoints"):  # the walk's own rows all kept
        assert getattr(t, name).equals(getattr(clean, name)), name
    with pytest.raises(SurveyFormatError) as info:
        parse_trace_bytes(_text(STRAY), path="walk.txt", strict=True)
    assert info.value.reason == "time_outlier" and info.value.line == n + 1


def test_a_row_within_the_bound_is_kept_and_batches_read_as_single_files(tmp_path):
    t0 = int(small_trace(n=200).sensors["t_ms"].median())
    near = t0 + MAX_FROM_MEDIAN_TIME_MS - 60_000  # 11 h 59 min later: a long walk, kept
    t = parse_trace_bytes(_text(f"{near}\tTYPE_WAYPOINT\t5\t5\n"), path="w.txt")
    assert not t.report.bad and near in t.waypoints["t_ms"].to_list()
    # files read together in one batch: each judged by its own rows
    (tmp_path / "a.txt").write_bytes(_text(STRAY))
    (tmp_path / "b.txt").write_bytes(_text())
    both = list(iter_traces([tmp_path / "a.txt", tmp_path / "b.txt"]))
    assert [x.report.bad for x in both] == [{"time_outlier": 2}, {}]


def test_many_stray_rows_each_file_reports_its_first_ones_in_full(tmp_path):
    """Messages are written only for the rows a report can show (each file's first
    MAX_MESSAGES bad lines; a log half on another clock has 10^5 or more): every shown one
    names its own line, type and time, in both files of one batch, and strict mode the first."""
    from survey.trace_reader import MAX_MESSAGES

    n_stray = 3 * MAX_MESSAGES
    stray = "".join(f"{i}\tTYPE_{'GYROSCOPE' if i % 3 else 'ACCELEROMETER'}\t1\t2\t3\t3\n"
                    for i in range(n_stray))
    clean_lines = parse_trace_bytes(_text(), path="x.txt").report.lines_total
    for name in ("a.txt", "b.txt"):
        (tmp_path / name).write_bytes(_text(stray))
    for t in iter_traces([tmp_path / "a.txt", tmp_path / "b.txt"]):
        r = t.report
        assert r.bad == {"time_outlier": n_stray} and len(r.messages) == MAX_MESSAGES
        for k, msg in enumerate(r.messages):
            kind = "GYROSCOPE" if k % 3 else "ACCELEROMETER"
            assert msg.startswith(f"{t.report.path}:{clean_lines + k + 1}: TYPE_{kind}: time "
                                  f"{k} ms is over 12 h from the median time"), msg
    with pytest.raises(SurveyFormatError) as info:
        parse_trace_bytes(_text(stray), path="walk.txt", strict=True)
    assert info.value.line == clean_lines + 1 and "TYPE_ACCELEROMETER: time 0 ms" in str(
        info.value)


def test_a_whole_stream_on_another_clock_is_kept_for_the_clock_check():
    """Wi-Fi stamped with the time since boot: every scan is far from the sensors, but the
    scans agree with each other, so none is an outlier and clock_mismatch says why."""
    t = parse_trace_bytes(_text(shift_wifi_ms=-1_500_000_000_000), path="walk.txt")
    assert not t.report.bad and len(t.wifi)
    assert "different clocks" in t.clock_mismatch()


def test_far_from_median_time_subsampled_medians_flag_the_same_rows():
    rng = np.random.default_rng(0)
    n = 300_000
    group = np.sort(rng.integers(0, 5, n))
    t = 1.6e12 + rng.uniform(0, 3.6e6, n) + group * 1e9
    t[[7, 150_000, n - 1]] = [0.0, 1.6e12 + 5e13, 0.0]
    tiny = np.array([1.6e12, 1.6e12 + 1000, 0.0])  # a group of three (a walk's waypoints)
    # a group of 100 rows with one stray, the first of it: sampled once in a batch-wide
    # stride, the stray was the group's "median" and its 99 good rows were flagged
    small = np.r_[0.0, 1.6e12 + 20.0 * np.arange(99)]
    far = far_from_median_time(np.r_[t, tiny, small],
                               np.r_[group, [5, 5, 5], np.full(100, 6)], 7, per_group=200)
    assert np.flatnonzero(far).tolist() == [7, 150_000, n - 1, n + 2, n + 3]


def test_step_detection_refuses_a_span_no_walk_has():
    t = np.r_[0.0, 1.6e12 + 20.0 * np.arange(500)]
    acc = np.tile([0.0, 0.0, 9.81], (len(t), 1))
    with pytest.raises(ProcessingError, match=r"accelerometer times span .* h"):
        detect_steps(t, acc)
