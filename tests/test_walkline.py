"""indoormap's own walk-line format (GeoJSON plan + sensor CSV) into the same store."""

from __future__ import annotations

import json
import re
import sys

import numpy as np
import pytest

from survey.errors import SurveyFormatError
from survey.ingest import ingest
from survey.store import SurveyStore
from survey.walkline import read_walk_plan


T0 = 1_700_000_000_000  # the sensor logs' first time (Unix ms)


def _csv(path, n=100, t0=T0, extra_bad_row=False):
    rng = np.random.default_rng(1)
    cols = ["t_ms", "acc_x", "acc_y", "acc_z", "mag_x", "mag_y", "mag_z", "rot_x", "rot_y",
            "rot_z", "mag_uncal_x", "mag_uncal_y", "mag_uncal_z", "mag_bias_x", "mag_bias_y",
            "mag_bias_z"]
    rows = [",".join(cols)]
    for i in range(n):
        vals = rng.normal(0, 1, len(cols) - 1)
        vals[6:9] *= 0.3  # rot_x..rot_z: a unit quaternion's parts
        rows.append(",".join([str(t0 + 20 * i)] + [f"{v:.6f}" for v in vals]))
    if extra_bad_row:
        rows.insert(5, ",".join([str(t0 + 3)] + ["oops"] + ["1"] * (len(cols) - 2)))
    path.write_text("\n".join(rows) + "\n")


def _plan(tmp_path, features):
    plan = {"type": "FeatureCollection",
            "properties": {"site_id": "siteW", "floor_name": "F2", "device_model": "Pixel"},
            "features": features}
    p = tmp_path / "plan.geojson"
    p.write_text(json.dumps(plan))
    return p


def _feature(walk_id, coords, **props):
    return {"type": "Feature", "geometry": {"type": "LineString", "coordinates": coords},
            "properties": {"walk_id": walk_id, "sensor_log": f"{walk_id}.csv", **props}}


def test_plan_with_both_time_styles_lands_in_store(tmp_path):
    _csv(tmp_path / "a.csv")
    _csv(tmp_path / "b.csv")
    plan = _plan(tmp_path, [
        _feature("a", [[0, 0], [3, 0], [3, 4]], start_ms=1_700_000_000_000,
                 end_ms=1_700_000_007_000),
        _feature("b", [[0, 0], [0, 10]], vertex_times_ms=[1_700_000_000_000, 1_700_000_001_980]),
    ])
    walks = read_walk_plan(plan)
    a = walks[0][0]
    # steady pace: the corner at 3 m of 7 m is reached at 3/7 of the time
    assert list(a.waypoints["t_ms"]) == [1_700_000_000_000, 1_700_000_003_000, 1_700_000_007_000]
    assert list(a.waypoints["x_m"]) == [0, 3, 3]
    assert a.header.site_id == "siteW" and a.header.model == "Pixel"
    assert set(a.sensors["stream"].astype(str)) == {"accelerometer", "magnetic_field",
                                                    "rotation_vector",
                                                    "magnetic_field_uncalibrated"}
    unc = a.stream("magnetic_field_uncalibrated")
    assert unc["bx"].notna().all() and a.stream("magnetic_field")["bx"].isna().all()
    s = ingest([plan], tmp_path / "store")
    assert s.status_counts() == {"new": 2}
    store = SurveyStore.open(tmp_path / "store")
    cat = store.catalog()
    assert list(cat["source_format"]) == ["walkline", "walkline"]
    assert set(cat["floor"]) == {"F2"}
    assert len(store.table("waypoints", trace_ids=["b"])) == 2
    assert ingest([plan], tmp_path / "store").status_counts() == {"unchanged": 2}
    _csv(tmp_path / "b.csv", n=50)  # the log changed: b is replaced
    assert ingest([plan], tmp_path / "store").status_counts() == {"unchanged": 1, "changed": 1}
    assert len(store.table("sensors", trace_ids=["b"])) == 4 * 50


def test_a_walk_whose_log_is_missing_fails_alone(tmp_path):
    """Ingest read a plan's every log before storing any: one missing log failed the plan's
    every walk. Now that walk fails, named by its feature, and the others are stored; a
    strict ingest still stops at it."""
    _csv(tmp_path / "a.csv")
    _csv(tmp_path / "c.csv")
    plan = _plan(tmp_path, [_feature(w, [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980)
                            for w in ("a", "b", "c")])
    summary = ingest([plan], tmp_path / "store")
    assert {o.trace_id: o.status for o in summary.outcomes} == {"a": "new", "b": "failed",
                                                               "c": "new"}
    failed, = summary.failed
    assert failed.path == f"{plan} (feature 1)" and "sensor log 'b.csv' not readable" in \
        failed.detail
    assert set(SurveyStore.open(tmp_path / "store").catalog()["trace_id"]) == {"a", "c"}
    with pytest.raises(SurveyFormatError, match=r"feature 1.*'b.csv' not readable"):
        ingest([plan], tmp_path / "strict", strict=True)
    assert not (tmp_path / "strict" / "catalog.parquet").exists()


def test_bad_csv_row_lenient_and_strict(tmp_path):
    _csv(tmp_path / "a.csv", extra_bad_row=True)
    plan = _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980)])
    (trace, _, _), = read_walk_plan(plan)
    assert trace.report.bad == {"non_numeric": 1}
    # the line and the column (a log has a dozen): before, the line alone
    assert trace.report.messages[0].endswith("a.csv:6: non-numeric, missing or non-finite "
                                             "value: column acc_x ('oops')")
    with pytest.raises(SurveyFormatError, match=r"a.csv:6: non-numeric"):
        read_walk_plan(plan, strict=True)


def test_an_unchanged_walk_is_not_parsed_again(tmp_path, monkeypatch):
    """A stored walk of a plan is hashed before it is parsed, as a trace file is: an
    unchanged one is skipped unread, so ``--strict`` does not raise on a bad row it was
    stored with (a trace file's was never raised on), and a changed one still is."""
    from survey.walkline import PlanWalk

    _csv(tmp_path / "a.csv", extra_bad_row=True)
    _csv(tmp_path / "b.csv")
    plan = _plan(tmp_path, [_feature(w, [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980)
                            for w in ("a", "b")])
    assert ingest([plan], tmp_path / "store").status_counts() == {"new": 2}
    parsed = []
    real_parse = PlanWalk.parse
    monkeypatch.setattr(PlanWalk, "parse", lambda self, *a, **k: (
        parsed.append(self.walk_id), real_parse(self, *a, **k))[1])
    again = ingest([plan], tmp_path / "store", strict=True)
    assert again.status_counts() == {"unchanged": 2} and parsed == []
    _csv(tmp_path / "b.csv", n=50)
    assert ingest([plan], tmp_path / "store", strict=True).status_counts() == {
        "unchanged": 1, "changed": 1}
    assert parsed == ["b"]
    _csv(tmp_path / "a.csv", n=60, extra_bad_row=True)  # changed, with its bad row: raised
    with pytest.raises(SurveyFormatError, match=r"a.csv:6: non-numeric"):
        ingest([plan], tmp_path / "store", strict=True)
    lenient = ingest([plan], tmp_path / "store")  # and without --strict, stored and counted
    assert lenient.status_counts() == {"changed": 1, "unchanged": 1}
    assert lenient.bad == {"non_numeric": 1}


@pytest.mark.parametrize("row,message", [
    ("1,,3,", "non-numeric, missing or non-finite value: column acc_y (empty)"),
    ("1,2,inf,", "non-numeric, missing or non-finite value: column acc_z (inf)"),
    (",,,", "non-numeric, missing or non-finite value: no sensor column filled"),
    ("1,2,3,2.5", "non-numeric, missing or non-finite value: column accuracy (2.5)"),
    ("1,5000,3,", "a sensor value no phone reports (e.g. beyond 2000 m/s^2): column acc_y "
                  "(5000)"),
    ("1,2,3,300", "beyond 127 .*: column accuracy (300)")])
def test_a_bad_row_is_named_by_line_and_column(tmp_path, row, message):
    """A walk-line log has a dozen columns: its bad-line messages named the line alone."""
    good = "".join(f"{T0 + 20 * i},1,2,3,\n" for i in range(30))
    (tmp_path / "a.csv").write_text(f"t_ms,acc_x,acc_y,acc_z,accuracy\n{good}{T0 + 601},"
                                    f"{row}\n")
    plan = _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 580)])
    (trace, _, _), = read_walk_plan(plan)
    assert len(trace.report.messages) == 1, trace.report.messages
    assert re.search(re.escape("a.csv:32: ") + ".*" + re.escape(message.split(".*")[-1])
                     + "$", trace.report.messages[0]), trace.report.messages[0]
    assert message.split(".*")[0] in trace.report.messages[0]


@pytest.mark.parametrize("feature,message", [
    (_feature("a", [[0, 0], [1, 0]], start_ms=5, end_ms=5), "strictly increasing"),
    (_feature("a", [[0, 0], [1, 0]], vertex_times_ms=[1]), "1 values for 2 vertices"),
    (_feature("a", [[0, 0], [1, 0]]), "needs 'start_ms' and 'end_ms'"),
    (_feature("a", [[0, 0]], start_ms=1, end_ms=2), "at least two"),
    ({"type": "Feature", "geometry": {"type": "Point", "coordinates": [0, 0]},
      "properties": {}}, "LineString"),
    (_feature("missing", [[0, 0], [1, 0]], start_ms=1, end_ms=2), "sensor log 'missing.csv'"),
    # finite but far: it passed ingest and crashed `process` for every walk of the store
    (_feature("a", [[0, 0], [1e200, 4.4]], vertex_times_ms=[1, 2]), "beyond \\+-1e\\+08 m"),
    (_feature("a", [["27.8", "4.4"], [1, 0]], start_ms=1, end_ms=2), "JSON numbers"),
    (_feature("a", [[True, 0], [1, 0]], start_ms=1, end_ms=2), "JSON numbers"),
])
def test_plan_errors_name_file_and_feature(tmp_path, feature, message):
    _csv(tmp_path / "a.csv")
    plan = _plan(tmp_path, [feature])
    with pytest.raises(SurveyFormatError, match=message) as info:
        read_walk_plan(plan)
    assert "plan.geojson (feature 0)" in str(info.value)


def test_a_walk_without_ground_truth_has_no_waypoints(tmp_path):
    """A feature without geometry is a walk recorded with no ground truth (a production
    walk to localize): it was refused ("walk geometry must be a LineString"), so such a walk
    could only be localized by inventing a line. It reads with no waypoints, at the time its
    start_ms and end_ms give, or else at its sensor log's median time (a row 13 h from it is
    a stray)."""
    _csv(tmp_path / "a.csv")
    with (tmp_path / "a.csv").open("a") as f:
        f.write(f"{T0 + 13 * 3_600_000},0,0,9.8,1,1,1,0,0,0,1,1,1,0,0,0\n")
    bare = {"type": "Feature", "geometry": None, "properties": {"walk_id": "a",
                                                                "sensor_log": "a.csv"}}
    timed = json.loads(json.dumps(bare))
    timed["properties"].update(walk_id="b", start_ms=T0, end_ms=T0 + 1980)
    (a, _, _), (b, _, _) = read_walk_plan(_plan(tmp_path, [bare, timed]))
    for trace in (a, b):
        assert trace.waypoints.empty and trace.header.floor_name == "F2"
        assert trace.sensors["t_ms"].max() == T0 + 1980
        assert trace.report.bad == {"time_outlier": 1}
    assert (a.header.start_ms, b.header.start_ms, b.header.end_ms) == (None, T0, T0 + 1980)
    for times, message in (({"start_ms": T0, "end_ms": T0 - 1}, "the start not after the end"),
                           ({"start_ms": "noon", "end_ms": T0}, "must be numbers"),
                           ({"start_ms": T0}, "gives both start_ms and end_ms, or neither"),
                           ({"start_ms": [T0], "end_ms": T0}, "must be numbers")):
        bad = json.loads(json.dumps(bare))
        bad["properties"].update(times)
        with pytest.raises(SurveyFormatError, match=message):
            read_walk_plan(_plan(tmp_path, [bad]))
    # only an explicit null means no ground truth: a missing key (a typo, "geom") or an
    # empty object is refused, not read as a walk that then drops out of the map
    for broken in ({k: v for k, v in bare.items() if k != "geometry"},
                   {**bare, "geometry": {}}, {**bare, "geometry": []}):
        with pytest.raises(SurveyFormatError, match="geometry"):
            read_walk_plan(_plan(tmp_path, [broken]))


@pytest.mark.parametrize("scale, unit", [(1e-3, "seconds"), (1e3, "microseconds"),
                                         (1e6, "nanoseconds")])
def test_a_sensor_csv_alone_in_another_time_unit_says_which(tmp_path, scale, unit):
    """A walk without a plan's times (a sensor CSV given alone, a feature without geometry)
    is placed by its own times: in seconds they were read as January 1970 ms, most rows
    dropped as repeats, and the walk ended in "no steps detected"."""
    from survey.walkline import sensor_log_walk

    _csv(tmp_path / "a.csv", t0=int(T0 * scale) if scale < 1 else T0)
    if scale > 1:
        text = (tmp_path / "a.csv").read_text().splitlines()
        rows = [f"{int(int(r.split(',', 1)[0]) * scale)},{r.split(',', 1)[1]}" for r in text[1:]]
        (tmp_path / "a.csv").write_text("\n".join([text[0], *rows]) + "\n")
    with pytest.raises(SurveyFormatError, match=rf"a.csv: the log's t_ms .* look like {unit}, "
                                                r"not Unix milliseconds") as err:
        sensor_log_walk(tmp_path / "a.csv").read()
    assert err.value.reason == "clock"


def test_a_sensor_csv_ingested_alone_says_how_it_is_read(tmp_path):
    """A walk-line sensor CSV given to ingest without its plan is no trace file; the error
    says it is read through its walk plan (it said only "not a trace file")."""
    _csv(tmp_path / "a.csv")
    failed, = ingest([tmp_path / "a.csv"], tmp_path / "store").failed
    assert "not a trace file" in failed.detail
    assert "a walk-line sensor CSV is ingested through the walk plan naming it" in failed.detail


def test_csv_errors(tmp_path):
    (tmp_path / "a.csv").write_text("time,acc_x\n1,2\n")
    plan = _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980)])
    with pytest.raises(SurveyFormatError, match="needs a 't_ms' column"):
        read_walk_plan(plan)
    # a semicolon or tab for a comma: the header is one column named as the whole line
    for sep, said in ((";", "';'"), ("\t", "tab")):
        (tmp_path / "a.csv").write_text(sep.join(["t_ms", "acc_x", "acc_y", "acc_z"])
                                        + "\n" + sep.join("1234") + "\n")
        with pytest.raises(SurveyFormatError, match=f"its header is one column, .*must be "
                           f"comma-separated, not {said}-separated"):
            read_walk_plan(plan)
    (tmp_path / "a.csv").write_text("t_ms,acc_x,acc_y\n1,2,3\n")
    with pytest.raises(SurveyFormatError, match="missing \\['acc_z'\\]"):
        read_walk_plan(plan)
    (tmp_path / "plan2.geojson").write_text("{not json")
    with pytest.raises(SurveyFormatError, match="plan2.geojson: not a readable GeoJSON"):
        read_walk_plan(tmp_path / "plan2.geojson")


def test_folders_ignore_geojson_that_is_not_a_walk_plan(tmp_path):
    _csv(tmp_path / "a.csv")
    _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980)])
    (tmp_path / "floor.geojson").write_text(json.dumps(
        {"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {},
                                                    "geometry": None}]}))
    s = ingest([tmp_path], tmp_path / "store")
    assert s.status_counts() == {"new": 1}
    # named explicitly it is a plan, and a broken one: failed (lenient) or an error (strict)
    s = ingest([tmp_path / "floor.geojson"], tmp_path / "store")
    assert [o.status for o in s.outcomes] == ["failed"]
    assert "floor.geojson (feature 0)" in s.outcomes[0].detail
    with pytest.raises(SurveyFormatError, match=r"floor.geojson \(feature 0\)"):
        ingest([tmp_path / "floor.geojson"], tmp_path / "store", strict=True)


def test_sensor_log_must_be_a_regular_file(tmp_path):
    plan = _plan(tmp_path, [{"type": "Feature",
                             "geometry": {"type": "LineString", "coordinates": [[0, 0], [1, 0]]},
                             "properties": {"walk_id": "a", "sensor_log": "/dev/zero",
                                            "start_ms": 1, "end_ms": 2}}])
    with pytest.raises(SurveyFormatError, match="not a regular file"):
        read_walk_plan(plan)


def test_a_walk_id_cannot_place_files_outside_the_store(tmp_path):
    _csv(tmp_path / "a.csv")
    feature = _feature("a", [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980)
    feature["properties"]["walk_id"] = "../../../../outside"
    _plan(tmp_path, [feature])
    store_dir = tmp_path / "deep" / "store"
    ingest([tmp_path / "plan.geojson"], store_dir)
    written = [p for p in tmp_path.rglob("*.parquet")]
    assert written and all(store_dir in p.parents for p in written)
    assert SurveyStore.open(store_dir).catalog()["trace_id"].tolist() == ["../../../../outside"]


def test_a_changed_collection_property_changes_the_walk(tmp_path):
    _csv(tmp_path / "a.csv")
    plan = _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980)])
    ingest([plan], tmp_path / "store")
    doc = json.loads(plan.read_text())
    doc["properties"]["floor_name"] = "F3"
    plan.write_text(json.dumps(doc))
    s = ingest([plan], tmp_path / "store")
    assert s.status_counts() == {"changed": 1}
    assert SurveyStore.open(tmp_path / "store").catalog()["floor"].tolist() == ["F3"]


def test_accuracy_must_be_a_whole_number_and_lines_count_blank_ones(tmp_path):
    (tmp_path / "a.csv").write_text("t_ms,acc_x,acc_y,acc_z,accuracy\n1000,1,2,3,2\n\n"
                                    "1020,1,2,3,abc\n1040,1,2,3,2.5\n1060,1,2,3,\n")
    _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=1000, end_ms=1060)])
    (trace, _, _), = read_walk_plan(tmp_path / "plan.geojson")
    assert trace.sensors["t_ms"].tolist() == [1000, 1060]
    assert trace.sensors["accuracy"].tolist() == [2, 3]   # missing means 3
    assert [m.split(": ")[0].rsplit(":", 1)[1] for m in trace.report.messages] == ["4", "5"]
    with pytest.raises(SurveyFormatError, match=r"a.csv:4: non-numeric"):
        read_walk_plan(tmp_path / "plan.geojson", strict=True)


def test_a_sensor_value_no_phone_reports_is_out_of_range(tmp_path):
    """As in the trace reader: one accelerometer value of 1e30 is a corrupt sample (it made
    phantom steps), an out_of_range bad line."""
    (tmp_path / "a.csv").write_text("t_ms,acc_x,acc_y,acc_z,rot_x,rot_y,rot_z\n"
                                    "1000,1,2,3,0.1,0.2,0.3\n1020,1e30,2,3,0.1,0.2,0.3\n"
                                    "1040,1,2,3,0.1,2.5,0.3\n1060,1,2,3,0.1,0.2,0.3\n")
    _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=1000, end_ms=1060)])
    (trace, _, _), = read_walk_plan(tmp_path / "plan.geojson")
    assert sorted(set(trace.sensors["t_ms"])) == [1000, 1060]
    assert trace.report.bad == {"out_of_range": 2}
    with pytest.raises(SurveyFormatError, match=r"a.csv:3: .*no phone reports"):
        read_walk_plan(tmp_path / "plan.geojson", strict=True)


def test_a_row_far_in_time_is_a_time_outlier(tmp_path):
    """As in the trace reader (tests/test_trace_time_outliers.py): a row at time 0 among
    rows of 2019 is a time_outlier bad line, measured from the plan's vertex times, not a
    sample that made step detection span 49 years (before session 39 the walk-plan CSV
    kept it)."""
    t0 = 1_565_000_000_000
    rows = "".join(f"{t0 + 20 * i},1,2,3\n" for i in range(50))
    (tmp_path / "a.csv").write_text("t_ms,acc_x,acc_y,acc_z\n" + rows[:80] + "0,1,2,3\n"
                                    + rows[80:])
    _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=t0, end_ms=t0 + 980)])
    (trace, _, _), = read_walk_plan(tmp_path / "plan.geojson")
    assert trace.sensors["t_ms"].min() == t0 and len(trace.sensors) == 50
    assert trace.report.bad == {"time_outlier": 1}
    assert trace.report.messages == [f"{tmp_path / 'a.csv'}:6: t_ms is over 12 h from the "
                                     "walk's time (a wrong clock or a stray row): column t_ms "
                                     "(0)"]
    with pytest.raises(SurveyFormatError, match=r"a.csv:6: t_ms is over 12 h"):
        read_walk_plan(tmp_path / "plan.geojson", strict=True)
    # measured from the plan's times: of two rows, the one at time 0 is the stray
    (tmp_path / "a.csv").write_text(f"t_ms,acc_x,acc_y,acc_z\n{t0},1,2,3\n0,1,2,3\n")
    (trace, _, _), = read_walk_plan(tmp_path / "plan.geojson")
    assert trace.sensors["t_ms"].tolist() == [t0] and trace.report.bad == {"time_outlier": 1}
    # a log wholly on another clock than its plan is refused, named
    (tmp_path / "a.csv").write_text("t_ms,acc_x,acc_y,acc_z\n" + rows.replace("15650", "15750"))
    with pytest.raises(SurveyFormatError, match=r"a.csv: every row's t_ms is over 12 h from "
                                                r"the walk's time \(\d+ ms, the median of its "
                                                r"plan's vertex times"):
        read_walk_plan(tmp_path / "plan.geojson")


@pytest.mark.parametrize("scale, offset, message", [
    (1e-3, 0, r"the log's t_ms \(median 1\.565e\+09\) are a thousandth of the walk's time "
              r"\(1565000000490 ms, the median of its plan's vertex times.*\): the log in "
              r"seconds, or the plan in microseconds\? Both are Unix milliseconds"),
    (1e3, 0, r"are a thousand times the walk's time .*: the log in microseconds, "
             r"or the plan in seconds\?"),
    (1e6, 0, r"are a million times .*: the log in nanoseconds\?"),  # beyond 2^53: unusable
    (1.0, 3.6e6 * 13, r"every row's t_ms is over 12 h from the walk's time .*: the log is on "
                      r"another clock"),
])
def test_a_log_in_another_time_unit_says_which(tmp_path, scale, offset, message):
    """A log stamped in seconds, microseconds or nanoseconds was refused as on 'different
    clocks' (nanoseconds: every row out of range, then 'no sample'); the ratio of its times
    to the plan's now names the unit. A log 13 h off is still on another clock."""
    t0 = 1_565_000_000_000
    rows = "".join(f"{(t0 + 20 * i) * scale + offset:.0f},1,2,3\n" for i in range(50))
    (tmp_path / "a.csv").write_text("t_ms,acc_x,acc_y,acc_z\n" + rows)
    _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=t0, end_ms=t0 + 980)])
    with pytest.raises(SurveyFormatError, match=message) as err:
        read_walk_plan(tmp_path / "plan.geojson")
    assert err.value.reason == "clock" and "a.csv" in str(err.value)


def test_a_row_of_the_wrong_width_is_one_bad_line(tmp_path):
    """A row with too few or too many fields (a logger killed mid-row leaves a cut last row)
    is one `field_count` bad line, numbered as the file's lines (blank ones counted), in
    order with the other bad lines; strict mode names the first. Before, the whole walk was
    refused as an unreadable CSV."""
    (tmp_path / "a.csv").write_text("t_ms,acc_x,acc_y,acc_z\n1000,1,2,3\n\n1020,1,2\n"
                                    "1040,1,x,3\n1060,1,2,3,4\n1080,1,2,3\n1100,1")
    _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=1000, end_ms=1080)])
    (trace, _, _), = read_walk_plan(tmp_path / "plan.geojson")
    report = trace.report
    assert sorted(set(trace.sensors["t_ms"])) == [1000, 1080]
    assert report.bad == {"field_count": 3, "non_numeric": 1}
    assert [m.split(": ", 1)[0].rsplit(":", 1)[1] for m in report.messages] == ["4", "5", "6",
                                                                                "8"]
    assert report.messages[0].endswith("a.csv:4: 3 fields, the header has 4")
    assert report.accounted_lines() == report.lines_total == 7  # the blank line is not one
    with pytest.raises(SurveyFormatError, match=r"a.csv:4: 3 fields, the header has 4"):
        read_walk_plan(tmp_path / "plan.geojson", strict=True)
    (tmp_path / "a.csv").write_text("t_ms,acc_x,acc_y,acc_z\n1000;1;2;3\n1020;1;2;3\n")
    with pytest.raises(SurveyFormatError, match="no row has the header's 4 fields"):
        read_walk_plan(tmp_path / "plan.geojson")


def test_bytes_that_are_not_utf8_make_their_row_a_bad_line(tmp_path, monkeypatch):
    """A row holding bytes that are not UTF-8 is one bad line, named by its line, whether it
    also has the wrong width or only a value no number can be read from. Before, pyarrow could
    not report a wrong-width row holding them ("Exception ignored") and the whole file was
    refused as unreadable."""
    (tmp_path / "a.csv").write_bytes(b"t_ms,acc_x,acc_y,acc_z\n1000,1,2,3\n1020,1,2,3,\xff\xfe\n"
                                     b"1040,1,\xff,3\n1060,1,2,3\n")
    _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=1000, end_ms=1060)])
    ignored = []  # exceptions raised in pyarrow's callback go to sys.unraisablehook
    monkeypatch.setattr(sys, "unraisablehook", ignored.append)
    (trace, _, _), = read_walk_plan(tmp_path / "plan.geojson")
    assert not ignored
    assert sorted(set(trace.sensors["t_ms"])) == [1000, 1060]
    assert trace.report.bad == {"field_count": 1, "non_numeric": 1}
    assert trace.report.accounted_lines() == trace.report.lines_total == 5
    with pytest.raises(SurveyFormatError, match=r"a.csv:3: 5 fields, the header has 4"):
        read_walk_plan(tmp_path / "plan.geojson", strict=True)
    # a whole log saved as UTF-16 is said to be so, not read as a file of bad lines
    (tmp_path / "a.csv").write_bytes("t_ms,acc_x,acc_y,acc_z\n1000,1,2,3\n".encode("utf-16"))
    with pytest.raises(SurveyFormatError, match=r"a.csv: UTF-16 text \(little-endian\)"):
        read_walk_plan(tmp_path / "plan.geojson")


def test_the_simulators_route_file_is_named_as_such_and_its_path_said_once(tmp_path):
    """`ingest planned_routes.geojson` (a new user's guess): the failure says what the file is
    and what to ingest instead, naming the file once."""
    from click.testing import CliRunner

    from survey.cli import main

    routes = {"type": "FeatureCollection", "features": [{
        "type": "Feature", "geometry": {"type": "LineString", "coordinates": [[0, 0], [5, 0]]},
        "properties": {"walk_id": "w1", "start_ms": 1, "end_ms": 2, "floor": "F1"}}]}
    path = tmp_path / "planned_routes.geojson"
    path.write_text(json.dumps(routes))
    res = CliRunner().invoke(main, ["ingest", str(path), "--store", str(tmp_path / "store")])
    line = next(ln for ln in res.output.splitlines() if ln.startswith("FAILED"))
    assert line.count(str(path)) == 1
    assert "simulator's planned_routes.geojson" in line and "path_data_files/" in line


def test_streams_logged_at_their_own_rates_one_event_per_row(tmp_path):
    """A row may leave a whole stream's columns empty: it holds no sample of that stream
    (phones log sensors at their own rates, one event per row). Before, every such row was a
    bad line, the walk got no sensor row at all, and ingest still said it was stored."""
    lines = ["t_ms,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z"]
    for i in range(50):
        lines.append(f"{T0 + 20 * i},0.1,0.2,9.8,,,")           # accelerometer at 50 Hz
        if i % 2:
            lines.append(f"{T0 + 20 * i + 7},,,,20.5,-3,{-40 - i}")  # magnetometer at 25 Hz
    lines.append(f"{T0 + 2000},0.1,,9.8,,,")   # a stream filled in part: a bad line
    lines.append(f"{T0 + 2001},,,,,,")         # no sample of any stream: a bad line
    (tmp_path / "a.csv").write_text("\n".join(lines) + "\n")
    plan = _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980)])
    (trace, _, _), = read_walk_plan(plan)
    s = trace.sensors
    acc, mag = s[s["stream"] == "accelerometer"], s[s["stream"] == "magnetic_field"]
    assert len(acc) == 50 and len(mag) == 25
    np.testing.assert_array_equal(mag["t_ms"], T0 + 20 * np.arange(1, 50, 2) + 7)
    np.testing.assert_allclose(mag["z"], -40.0 - np.arange(1, 50, 2))
    assert trace.report.bad == {"non_numeric": 2}
    assert trace.report.records == {"SENSOR_ROW": 75}


def test_a_log_without_a_usable_row_is_refused(tmp_path):
    """Every row bad (or none): the walk has no sample, refused naming the log (it was stored
    empty, ingest exiting 0, and the build failed later for want of processed walks)."""
    plan = _plan(tmp_path, [_feature("a", [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980)])
    (tmp_path / "a.csv").write_text("t_ms,acc_x,acc_y,acc_z\n"
                                    + "".join(f"{T0 + i},x,1,2\n" for i in range(3)))
    with pytest.raises(SurveyFormatError, match=r"a.csv: sensor log has no sample: none of its "
                       r"3 rows is usable \(non_numeric 3; the first: .*a.csv:2: "):
        read_walk_plan(plan)
    (tmp_path / "a.csv").write_text("t_ms,acc_x,acc_y,acc_z\n")
    with pytest.raises(SurveyFormatError, match="sensor log has no sample: no rows"):
        read_walk_plan(plan)
    summary = ingest([plan], tmp_path / "store")
    assert summary.status_counts() == {"failed": 1}
    assert "sensor log has no sample" in summary.failed[0].detail


def test_walks_that_record_no_floor_take_their_folders(tmp_path):
    """A walk plan need not name its floor (the floor properties are optional): its walks
    were stored under `unknown_floor`, so `build --plan` named the bundle so and `--floor F1`
    was refused. `ingest(floor_names=)` gives such walks the floor of the input they are in;
    walks that name theirs keep it, and the catalog keeps what the plan said."""
    src = tmp_path / "src"
    src.mkdir()
    for walk in ("u1", "n1"):
        _csv(src / f"{walk}.csv")
    plan = _plan(src, [_feature("u1", [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980),
                       _feature("n1", [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980,
                                floor_name="B2")])
    doc = json.loads(plan.read_text())
    del doc["properties"]["floor_name"]
    plan.write_text(json.dumps(doc))
    ingest([src], tmp_path / "plain")
    cat = SurveyStore.open(tmp_path / "plain").catalog().set_index("trace_id")
    assert cat.loc["u1", "floor"] == "unknown_floor" and cat.loc["n1", "floor"] == "B2"
    ingest([src], tmp_path / "named", floor_names={src: "F3"})
    cat = SurveyStore.open(tmp_path / "named").catalog().set_index("trace_id")
    assert cat.loc["u1", "floor"] == "F3" and cat.loc["u1", "floor_name"] == ""
    assert cat.loc["n1", "floor"] == "B2"
    ingest([src], tmp_path / "other", floor_names={tmp_path / "elsewhere": "F3"})
    assert SurveyStore.open(tmp_path / "other").catalog().set_index(
        "trace_id").loc["u1", "floor"] == "unknown_floor"  # only under the input named
    # the deepest input named gives the floor (a site folder and its floor folder)
    ingest([src], tmp_path / "nested", floor_names={tmp_path: "SITE", src: "F4"})
    assert SurveyStore.open(tmp_path / "nested").catalog().set_index(
        "trace_id").loc["u1", "floor"] == "F4"
    # a kept store: the walk that records no floor moves to the floor it is now said to be
    # (it kept the first one, and a build then said its walks were of that floor); one
    # ingest without floor_names leaves it where it is
    for names, status, floor in (({src: "F5"}, "changed", "F5"), (None, "unchanged", "F5"),
                                 ({src: "F5"}, "unchanged", "F5")):
        summary = ingest([src], tmp_path / "plain", floor_names=names)
        assert {o.trace_id: o.status for o in summary.outcomes} == {"u1": status,
                                                                   "n1": "unchanged"}
        store = SurveyStore.open(tmp_path / "plain")
        assert store.catalog().set_index("trace_id").loc["u1", "floor"] == floor
    assert len(store.table("sensors", trace_ids=["u1"])) == 4 * 100  # old parts collected
    assert not list((tmp_path / "plain").rglob("floor=unknown_floor"))


def test_build_exclude_names_walk_plan_walks(tmp_path):
    """`build --exclude` takes a walk plan's walk by its walk_id or its sensor log's name
    (with or without .csv), before the work and after the ingest; it knew trace files only,
    so a walk-line survey could not hold a walk out."""
    import click

    from mapping.cli_build import check_exclude_early, excluded_walks

    src = tmp_path / "src"
    src.mkdir()
    for walk in ("w1", "w2"):
        _csv(src / f"{walk}.csv")
    _plan(src, [_feature(w, [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980)
                for w in ("w1", "w2")])
    for name in ("w1", "w1.csv"):
        check_exclude_early([name], [src])
    with pytest.raises(click.BadParameter, match="'w3' is no walk of this build"):
        check_exclude_early(["w3"], [src])
    # named as the reader names them: a numeric or padded walk_id, the log a link leads to
    from survey.walkline import plan_walk_names

    other = tmp_path / "other"
    other.mkdir()
    _csv(other / "real.csv")
    (other / "link.csv").symlink_to(other / "real.csv")
    feats = [_feature("x", [[0, 0], [1, 0]], start_ms=T0, end_ms=T0 + 1980) for _ in range(2)]
    feats[0]["properties"].update(walk_id=17, sensor_log="real.csv")
    feats[1]["properties"].update(walk_id=" w8 ", sensor_log="link.csv")
    assert plan_walk_names(_plan(other, feats)) == {"17", "w8", "real.csv", "real"}
    summary = ingest([src], tmp_path / "store")
    catalog = SurveyStore.open(tmp_path / "store").catalog()
    for name in ("w1", "w1.csv"):
        assert excluded_walks(catalog, summary, [src], [name], lambda msg: None,
                              floors=[]) == {"w1"}
