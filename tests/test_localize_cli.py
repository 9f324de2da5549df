"""``indoormap localize`` and ``indoormap evaluate``."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from localize_fixtures import SAMPLE, truth_bundles  # noqa: F401  (fixture)
from radio_fixtures import built  # noqa: F401  (fixture)

from localize.bundle import load_bundle
from survey.cli import main
from survey.step_summaries import waypoints_of
from survey.trace_reader import read_trace

F1_WALKS = SAMPLE / "F1" / "path_data_files"


def test_localize_writes_positions_and_plots(truth_bundles, tmp_path):  # noqa: F811
    walk = min(F1_WALKS.glob("*.txt.gz"))
    res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), str(walk), "-o",
                                    str(tmp_path / "out"), "--particles", "200"])
    assert res.exit_code == 0, res.output
    tid = walk.name.split(".")[0]
    table = pq.read_table(tmp_path / "out" / f"{tid}.parquet")
    assert {"step", "t_ms", "x_m", "y_m", "spread_m"} <= set(table.column_names)
    assert table.num_rows > 20 and np.isfinite(table.column("x_m").to_numpy()).all()
    assert table.schema.metadata[b"method"] == b"indoormap"
    assert table.schema.metadata[b"smoothed"] == b"false"
    # what ran and on which map: auto's guided filter and the plain one wrote the same
    # metadata (method: indoormap), and no bundle id
    assert table.schema.metadata[b"ran"] == b"indoormap"
    assert table.schema.metadata[b"bundle_id"] == \
        load_bundle(truth_bundles["F1"]).bundle_id.encode()
    assert table.schema.metadata[b"auto"] == b"the bundle records no held-out map quality"
    assert (tmp_path / "out" / f"{tid}.png").stat().st_size > 1000
    assert "start first waypoint" in res.output
    # the walk's error at its waypoints is said (and in the plot's title), as evaluate scores it
    said = re.search(r"error at its (\d+) waypoints median ([\d.]+) m, max ([\d.]+) m",
                     res.output)
    assert said and int(said.group(1)) == len(waypoints_of(read_trace(walk))[0]), res.output
    scored = CliRunner().invoke(main, ["evaluate", str(truth_bundles["F1"]), str(walk),
                                       "--particles", "200"])
    row = next(ln.split() for ln in scored.stdout.splitlines() if ln.startswith("auto"))
    assert float(said.group(2)) == pytest.approx(float(row[3]), abs=0.051)  # its median


def test_waypoint_numbers_at_one_place_are_written_once():
    """Waypoints clicked at one place (a loop's start and end) get one label, "1, 7", not
    two numbers drawn over each other; places 0.6 m apart keep their own."""
    from localize.plots import _waypoint_labels

    xy = np.array([[0.0, 0.0], [5, 0], [5, 5], [5.6, 5], [0.3, 0.2], [5.1, 0.1]])
    assert [label for _, label in _waypoint_labels(xy)] == ["1, 5", "2, 6", "3", "4"]


def test_localize_csv_on_a_folder_of_bundles(truth_bundles, tmp_path):  # noqa: F811
    walk = min((SAMPLE / "F2" / "path_data_files").glob("*.txt.gz"))
    bundles = truth_bundles["F1"].parent  # holds F1 and F2: the walk's floor decides
    res = CliRunner().invoke(main, ["localize", str(bundles), str(walk), "-o", str(tmp_path),
                                    "--format", "csv", "--no-plot", "--method", "pdr",
                                    "--start", "20,10"])
    assert res.exit_code == 0, res.output
    assert "(F2)" in res.output and "start given" in res.output
    assert "warning: start" not in res.output
    res = CliRunner().invoke(main, ["localize", str(bundles), str(walk), "-o", str(tmp_path),
                                    "--format", "csv", "--no-plot", "--method", "pdr",
                                    "--start", "12,30.5", "--overwrite"])
    assert res.exit_code == 0, res.output  # a start off the floor's area is said, not refused
    assert "warning: start 12,30.5 is off the reachable area of F2" in res.output
    far = CliRunner().invoke(main, ["localize", str(bundles), str(walk), "-o",
                                    str(tmp_path / "far"), "--no-plot", "--method", "pdr",
                                    "--start", "1000,1000"])
    assert far.exit_code == 1 and "more than 200 m off the floor's map" in far.output
    assert "warning: start" not in far.output  # said once, as the error
    assert len(list(tmp_path.glob("*.csv"))) == 1 and not list(tmp_path.glob("*.png"))
    # a CSV has no metadata: which walk, floor and method are columns (session 40)
    rows = pd.read_csv(next(tmp_path.glob("*.csv")), dtype={"trace_id": str})
    assert list(rows.columns[:6]) == ["trace_id", "floor_id", "method", "ran", "bundle_id",
                                      "step"]
    assert set(rows["trace_id"]) == {walk.name.split(".")[0]} and set(rows["method"]) == {"pdr"}
    assert set(rows["bundle_id"]) == {load_bundle(bundles / "F2").bundle_id}
    assert set(rows["floor_id"]) == {load_bundle(bundles / "F2").floor_id}


def test_localize_on_a_registry_site_folder(truth_bundles, tmp_path):  # noqa: F811
    """A registry's site folder is a folder of floor bundles: each floor's current version."""
    from mapping.registry import Registry

    reg = Registry(tmp_path / "reg")
    for f in ("F1", "F2"):
        reg.publish(truth_bundles[f])
    site = tmp_path / "reg" / load_bundle(truth_bundles["F1"]).site_id
    walk = min((SAMPLE / "F2" / "path_data_files").glob("*.txt.gz"))
    res = CliRunner().invoke(main, ["localize", str(site), str(walk), "-o", str(tmp_path / "o"),
                                    "--no-plot", "--method", "pdr", "--start", "20,10"])
    assert res.exit_code == 0, res.output
    assert "(F2)" in res.output


def test_localize_errors_exit_1(truth_bundles, tmp_path):  # noqa: F811
    walk = min((SAMPLE / "F2" / "path_data_files").glob("*.txt.gz"))
    res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), str(walk), "-o",
                                    str(tmp_path)])
    assert res.exit_code == 1
    assert "floor" in res.output
    f1_walk = min((SAMPLE / "F1" / "path_data_files").glob("*.txt.gz"))
    for start in ("nonsense", "nan,nan", "1,inf"):
        res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), str(f1_walk),
                                        "-o", str(tmp_path), "--start", start])
        assert res.exit_code == 2 and "Invalid value for --start" in res.output, res.output
    # truth bundles carry no fingerprints: a start at the radio fix names the option to change
    res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), str(f1_walk), "-o",
                                    str(tmp_path), "--start", "radio"])
    assert res.exit_code == 1
    assert "needs a bundle with Wi-Fi or BLE fingerprints" in res.output
    assert "(--start radio)" in res.output, res.output


def test_evaluate_prints_errors_and_cdfs(truth_bundles, tmp_path):  # noqa: F811
    res = CliRunner().invoke(main, ["evaluate", str(truth_bundles["F1"]), str(F1_WALKS),
                                    "--method", "indoormap", "--method", "pdr",
                                    "--method", "auto",
                                    "--particles", "150", "--plot-file", str(tmp_path / "cdf.png"),
                                    "--csv", str(tmp_path / "errors.csv")])
    assert res.exit_code == 0, res.output
    lines = {ln.split()[0]: ln.split() for ln in res.stdout.splitlines() if ln.strip()}
    assert float(lines["indoormap"][2]) < float(lines["pdr"][2])  # median error
    # auto says what it ran (truth maps record no held-out quality: the filter), and equals it
    assert lines["auto"][1] == "(indoormap)" and lines["auto"][2:] == lines["indoormap"][1:]
    assert (tmp_path / "cdf.png").exists() and f"plot: {tmp_path / 'cdf.png'}" in res.stderr
    # every error as a row: the printed medians are those of the table's rows
    table = pd.read_csv(tmp_path / "errors.csv", dtype={"trace_id": str})
    assert table["trace_id"].nunique() == len(list(F1_WALKS.glob("*.txt.gz")))
    assert set(table.loc[table["method"] == "auto", "ran"]) == {"indoormap"}  # what it ran
    for method in ("indoormap", "pdr"):
        rows = table[table["method"] == method]
        assert float(lines[method][1]) == len(rows)
        assert float(lines[method][2]) == pytest.approx(rows["error_m"].median(), abs=0.006)
    assert np.allclose(np.hypot(table["est_x_m"] - table["x_m"], table["est_y_m"] - table["y_m"]),
                       table["error_m"])
    # an existing --plot-file or --csv is kept unless --overwrite, said before any walk is read
    res = CliRunner().invoke(main, ["evaluate", str(truth_bundles["F1"]), str(F1_WALKS),
                                    "--csv", str(tmp_path / "errors.csv")])
    assert res.exit_code == 1 and "errors.csv exists; pass --overwrite" in res.output


def test_smooth_option(truth_bundles, tmp_path):  # noqa: F811
    walk = min(F1_WALKS.glob("*.txt.gz"))
    res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), str(walk), "-o",
                                    str(tmp_path), "--particles", "150", "--no-plot",
                                    "--smooth"])
    assert res.exit_code == 0, res.output
    assert "smoothed steps" in res.output
    tid = walk.name.split(".")[0]
    assert [f.name for f in tmp_path.iterdir()] == [f"{tid}.smoothed.parquet"]  # told apart
    meta = pq.read_table(tmp_path / f"{tid}.smoothed.parquet").schema.metadata
    assert meta[b"smoothed"] == b"true"
    res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), str(walk), "-o",
                                    str(tmp_path), "--method", "pdr", "--smooth"])
    assert res.exit_code == 2 and "locate a walk offline (indoormap" in res.output
    res = CliRunner().invoke(main, ["evaluate", str(truth_bundles["F1"]), str(walk),
                                    "--methods", "indoormap,pdr,align", "--particles", "150",
                                    "--smooth"])
    assert res.exit_code == 0, res.output
    rows = {ln.split()[0] for ln in res.output.splitlines() if ln.strip()}
    assert {"indoormap", "indoormap+smoothed", "pdr", "align", "align+smoothed"} <= rows
    assert "pdr+smoothed" not in rows


def test_localize_reports_a_failing_walk_and_goes_on(truth_bundles, tmp_path):  # noqa: F811
    """A bad trace among good ones: named with its reason, the good walk still written, exit
    1; a second run refuses to replace outputs unless --overwrite; a run where every walk fails
    leaves no output folder behind."""
    good = min(F1_WALKS.glob("*.txt.gz"))
    junk = tmp_path / "junk.txt"
    junk.write_text("not a trace\n")
    out = tmp_path / "out"
    args = ["localize", str(truth_bundles["F1"]), str(good), str(junk), "-o", str(out),
            "--no-plot", "--particles", "100"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 1
    assert f"error: {junk}:" in res.output and "1 failure(s) in 2 walk(s)" in res.output
    tid = good.name.split(".")[0]
    first = (out / f"{tid}.parquet").read_bytes()
    again = CliRunner().invoke(main, args[:3] + args[4:])  # the good walk alone
    assert again.exit_code == 1 and "pass --overwrite" in again.output
    (out / f"{tid}.parquet").unlink()  # the plot is an output too
    (out / f"{tid}.png").write_bytes(b"keep")
    plotted = CliRunner().invoke(main, [a for a in args[:3] + args[4:] if a != "--no-plot"])
    assert plotted.exit_code == 1 and f"{tid}.png exists" in plotted.output
    assert (out / f"{tid}.png").read_bytes() == b"keep"
    again = CliRunner().invoke(main, args[:3] + args[4:] + ["--overwrite"])
    assert again.exit_code == 0, again.output
    assert (out / f"{tid}.parquet").read_bytes() == first  # same seed, same bytes
    nothing = tmp_path / "nothing"
    res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), str(junk), "-o",
                                    str(nothing)])
    assert res.exit_code == 1 and not nothing.exists()
    gone = tmp_path / "gone.txt.gz"  # a missing path fails alone, as a bad file does
    res = CliRunner().invoke(main, args[:3] + [str(gone)] + args[4:] + ["--overwrite"])
    assert res.exit_code == 1 and f"error: {gone}: no such file or folder" in res.output
    assert "1 failure(s) in 2 walk(s)" in res.output
    assert (out / f"{tid}.parquet").read_bytes() == first
    res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), str(gone), "-o",
                                    str(nothing)])
    assert res.exit_code == 1 and "1 failure(s) in 1 walk(s)" in res.output
    assert not nothing.exists()
    walk = min(F1_WALKS.glob("*.txt.gz"))  # walk.txt given for walk.txt.gz: said which exists
    typo = str(walk)[:-3]
    res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), typo, "-o",
                                    str(nothing)])
    assert res.exit_code == 1 and f"error: {typo}: no such file or folder (there is {walk})" \
        in res.output


def test_evaluate_goes_on_past_a_bad_walk_and_a_failing_method(truth_bundles,  # noqa: F811
                                                                tmp_path):
    """A junk file is an error (as in localize), and a method that cannot run on the bundle
    (radio without fingerprints) fails alone: the other rows keep every walk."""
    walks = sorted(F1_WALKS.glob("*.txt.gz"))[:2]
    junk = tmp_path / "junk.txt"
    junk.write_text("not a trace\n")
    gone = tmp_path / "gone.txt.gz"  # a path that does not exist is one failed walk too
    res = CliRunner().invoke(main, ["evaluate", str(truth_bundles["F1"]), *map(str, walks),
                                    str(junk), str(gone), "--methods", "pdr,radio", "--start",
                                    "waypoint"])
    assert res.exit_code == 1
    assert f"error: {junk}: no sensor sample, waypoint or scan" in res.output
    assert f"error: {gone}: no such file or folder" in res.output
    assert f"error: {walks[0]} (radio):" in res.output
    assert "4 failure(s) in 4 walk(s)" in res.output
    rows = {ln.split()[0]: ln.split() for ln in res.output.splitlines()
            if ln.startswith(("pdr ", "radio "))}
    assert int(rows["pdr"][1]) > 5 and int(rows["radio"][1]) == 0


def test_evaluate_usage_errors_and_plot_folder(truth_bundles, tmp_path):  # noqa: F811
    walk = min(F1_WALKS.glob("*.txt.gz"))
    res = CliRunner().invoke(main, ["evaluate", str(truth_bundles["F1"]), str(walk),
                                    "--method", " , "])
    assert res.exit_code == 2 and "no method given" in res.output
    plot = tmp_path / "new" / "folder" / "cdf.png"
    res = CliRunner().invoke(main, ["evaluate", str(truth_bundles["F1"]), str(walk),
                                    "--method", "pdr", "--method", "pdr,pdr", "--plot-file",
                                    str(plot)])
    assert res.exit_code == 0, res.output
    assert plot.stat().st_size > 1000
    from survey.step_summaries import waypoints_of
    from survey.trace_reader import read_trace

    n_wp = len(waypoints_of(read_trace(walk))[0])
    assert [ln.split()[:2] for ln in res.stdout.splitlines()[1:]] == [["pdr", str(n_wp)]]


def test_a_damaged_walk_is_localized_with_a_warning(truth_bundles, tmp_path):  # noqa: F811
    """Lines the reader had to skip are not silent: the file and the first problem are named."""
    import gzip

    walk = min(F1_WALKS.glob("*.txt.gz"))
    cut = tmp_path / walk.name.replace(".gz", "")
    lines = gzip.decompress(walk.read_bytes()).decode().splitlines(keepends=True)
    cut.write_text("".join(lines[:len(lines) // 2]) + "1600000000000\tTYPE_WIFI\tx\n")
    res = CliRunner().invoke(main, ["evaluate", str(truth_bundles["F1"]), str(cut),
                                    "--methods", "pdr"])
    assert res.exit_code == 0, res.output
    assert f"warning: {cut}: 1 bad line(s) skipped (" in res.output
    n = len(lines) // 2 + 1  # the file is named once, the bad line by its number
    assert f"; first: line {n}: " in res.output and res.output.count(str(cut)) == 1, res.output


def test_a_walk_whose_sensor_clock_differs_is_refused_by_name(truth_bundles, tmp_path):  # noqa: F811
    """Sensor samples stamped with the time since boot, scans and waypoints with Unix time:
    `localize` said "no Wi-Fi or BLE fix" and `evaluate` scored the waypoints against the
    track's last point (6 m, exit 0). Now the walk fails naming the clocks; the others go on."""
    import gzip

    walk = min(F1_WALKS.glob("*.txt.gz"))
    shifted = tmp_path / "boot_clock.txt"
    out = []
    for line in gzip.decompress(walk.read_bytes()).decode().splitlines(keepends=True):
        t, _, rest = line.partition("\t")
        if not line.startswith("#") and rest.startswith("TYPE_") and not rest.startswith(
                ("TYPE_WIFI", "TYPE_BEACON", "TYPE_WAYPOINT")):
            line = f"{int(t) - 1_678_000_000_000}\t{rest}"
        out.append(line)
    shifted.write_text("".join(out))
    res = CliRunner().invoke(main, ["evaluate", str(truth_bundles["F1"]), str(shifted),
                                    str(walk), "--methods", "pdr"])
    assert res.exit_code == 1, res.output
    assert f"{shifted}: its Wi-Fi scans (" in res.output
    assert "all lie outside the sensor samples' time span" in res.output
    assert "pdr" in res.output  # the good walk was scored


@pytest.mark.parametrize("args, code, message", [
    (["--plot-file", "{tmp}/cdf.txt"], 2, "the plot is a PNG; name it .png"),
    (["--plot-file", "{tmp}/x.png", "--csv", "{tmp}/x.png"], 2,
     "--plot-file and --csv name the same file"),
    (["--csv", "{tmp}/FILE/errors.csv"], 1, "FILE is a file, not a folder: "),
])
def test_evaluate_refuses_plot_and_csv_targets_before_the_work(truth_bundles, tmp_path,  # noqa: F811
                                                               args, code, message):
    """A .txt plot used to end the run in a matplotlib traceback; --csv and --plot-file on
    one file wrote the CSV, then the PNG over it."""
    (tmp_path / "FILE").write_text("keep me")
    walk = min(F1_WALKS.glob("*.txt.gz"))
    res = CliRunner().invoke(main, ["evaluate", str(truth_bundles["F1"]), str(walk),
                                    "--methods", "pdr",
                                    *[a.format(tmp=tmp_path) for a in args]])
    assert res.exit_code == code and message in res.output, res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["FILE"]


def test_two_walks_with_one_trace_id_in_a_run_are_refused(truth_bundles, tmp_path):  # noqa: F811
    """The second walk's outputs would replace the first one's <trace_id>.parquet and .png
    (and evaluate would merge their scores): it fails, named, and the first is kept."""
    first, other = sorted(F1_WALKS.glob("*.txt.gz"))[:2]
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / first.name).write_bytes(first.read_bytes())
    (tmp_path / "b" / first.name).write_bytes(other.read_bytes())  # same name, other walk
    for command in (["localize", "-o", str(tmp_path / "out"), "--method", "pdr"],
                    ["evaluate", "--methods", "pdr"]):
        res = CliRunner().invoke(main, [command[0], str(truth_bundles["F1"]),
                                        str(tmp_path / "a"), str(tmp_path / "b"),
                                        *command[1:]])
        assert res.exit_code == 1, res.output
        assert f"trace id {first.name.split('.')[0]} is also" in res.output
    tid = first.name.split(".")[0]
    kept = pq.read_table(tmp_path / "out" / f"{tid}.parquet")
    assert kept.num_rows > 0 and len(list((tmp_path / "out").iterdir())) == 2  # parquet, png
    # one file named twice (its folder, and a path to it through "..") is one walk
    once = CliRunner().invoke(main, ["evaluate", str(truth_bundles["F1"]),
                                     str(tmp_path / "a"), "--methods", "pdr"])
    twice = CliRunner().invoke(main, ["evaluate", str(truth_bundles["F1"]), str(tmp_path / "a"),
                                      str(tmp_path / "b" / ".." / "a" / first.name),
                                      "--methods", "pdr"])
    assert twice.exit_code == 0 and twice.stdout == once.stdout, twice.output  # same n


def test_evaluate_takes_the_new_option_spellings_and_still_the_old_ones(truth_bundles,  # noqa: F811
                                                                         tmp_path):
    """``--method`` (as localize spells it; comma-separated or repeated) and ``--plot-file``
    (a file, unlike localize's --plot/--no-plot switch) are documented; ``--methods`` and
    ``--plot`` still work, left out of --help. Checked before any walk is read."""
    def help_of(command: str) -> str:  # without spaces: click wraps it, hyphens too
        return "".join(CliRunner().invoke(main, [command, "--help"]).output.split())

    def squeezed(text: str) -> str:
        return "".join(text.split())

    help_text = help_of("evaluate")
    assert "--methodMETHOD[,METHOD...]" in help_text and "--plot-fileFILE" in help_text
    assert "--methods" not in help_text and "--plotFILE" not in help_text
    assert squeezed("as localize --smooth") in help_text
    walk = str(min(F1_WALKS.glob("*.txt.gz")))
    bundle = str(truth_bundles["F1"])
    for args in (["--method", "pdr", "--method", "nonsense,pdr"], ["--methods", "nonsense"],
                 ["--method", "pdr,nonsense", "--methods", "indoormap"]):
        res = CliRunner().invoke(main, ["evaluate", bundle, walk, *args])
        assert res.exit_code == 2, res.output
        assert "Invalid value for --method: unknown methods ['nonsense']" in res.output
    for spelling in ("--plot-file", "--plot"):
        res = CliRunner().invoke(main, ["evaluate", bundle, walk, "--method", "pdr", spelling,
                                        str(tmp_path / "cdf.txt")])
        assert res.exit_code == 2 and "Invalid value for --plot-file: " in res.output
        assert "the plot is a PNG" in res.output
    res = CliRunner().invoke(main, ["evaluate", bundle, walk, "--plot-file"])
    assert res.exit_code == 2 and "'--plot-file' requires an argument" in res.output
    res = CliRunner().invoke(main, ["evaluate", bundle, walk, "--plot", str(tmp_path)])
    assert res.exit_code == 2 and "Invalid value for '--plot-file': " in res.output  # not both
    assert squeezed("wifi-locate's --smoothing walk|forward") in help_of("localize")
    assert squeezed("(earlier and later scans: offline, as localize --smooth)") in \
        help_of("wifi-locate")


def test_localize_refuses_to_write_into_a_bundle_or_a_store(truth_bundles, tmp_path):  # noqa: F811
    """`-o BUNDLE` left an unlisted file that made the bundle fail its checks, and `-o STORE
    --overwrite` replaced the store's catalog.parquet with a track (a walk named catalog)."""
    import shutil

    walk = min(F1_WALKS.glob("*.txt.gz"))
    bundle = tmp_path / "F1"
    shutil.copytree(truth_bundles["F1"], bundle)
    store = tmp_path / "store"
    store.mkdir()
    (store / "store.json").write_text('{"schema_version": 1}')
    for out in (bundle, bundle / "tracks", store, store / "sub"):
        res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), str(walk), "-o",
                                        str(out), "--overwrite", "--no-plot"])
        assert res.exit_code == 2 and "write the results elsewhere" in res.output, res.output
    # evaluate's and survey-report's files likewise (before session 39 they were written)
    for command in (["evaluate", str(truth_bundles["F1"]), str(walk), "--methods", "pdr",
                     "--csv", str(bundle / "errors.csv")],
                    ["evaluate", str(truth_bundles["F1"]), str(walk), "--methods", "pdr",
                     "--plot-file", str(bundle / "layers" / "cdf.png")],
                    ["survey-report", "--store", str(store), "--csv", str(store / "qa.csv")]):
        res = CliRunner().invoke(main, command)
        assert res.exit_code == 2 and "write the results elsewhere" in res.output, res.output
        assert ("--csv" if "--csv" in command else "--plot-file") in res.output
    assert sorted(p.name for p in store.iterdir()) == ["store.json"]
    load_bundle(bundle)  # still whole
    assert not (bundle / "tracks").exists()
    # another program's manifest.json above the output is no bundle
    (tmp_path / "web").mkdir()
    (tmp_path / "web" / "manifest.json").write_text('{"name": "my app"}')
    res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), str(walk), "-o",
                                    str(tmp_path / "web" / "tracks"), "--no-plot"])
    assert res.exit_code == 0, res.output


def _as_walk_plan(trace_path, folder):
    """A trace file written as indoormap's walk-line format (``folder`` is created)."""
    from survey.walkline_writer import write_walk_plan

    return write_walk_plan(folder, [read_trace(trace_path)])


def test_a_walk_without_ground_truth_is_localized(built, tmp_path):  # noqa: F811
    """A walk-plan walk with no geometry (no ground truth, as a production walk has none):
    ``localize`` starts it from its first Wi-Fi fix and writes the track the same walk gives
    as a trace, with no error; one without scans needs ``--start``; ``evaluate`` skips
    them, having nothing to score against. Before, such a walk had to be given an invented
    line, and its 'error at its 2 waypoints' was printed."""
    import dataclasses

    from survey.walkline_writer import write_walk_plan

    walk = min(F1_WALKS.glob("*.txt.gz"))
    trace = read_trace(walk)
    blind = dataclasses.replace(trace, waypoints=trace.waypoints.iloc[:0])
    quiet = dataclasses.replace(blind, trace_id="quiet", wifi=trace.wifi.iloc[:0],
                                ble=trace.ble.iloc[:0])
    plan = write_walk_plan(tmp_path / "plan", [blind, quiet])
    bundles, runner = str(built), CliRunner()
    tracks = {}
    # (auto starts a walk with waypoints at its first one, as the PDR baseline does)
    for name, path, start in (("trace", walk, "radio"), ("plan", plan, "auto")):
        res = runner.invoke(main, ["localize", bundles, str(path), "-o", str(tmp_path / name),
                                   "--no-plot", "--method", "indoormap", "--start", start])
        assert "start first Wi-Fi fix" in res.output, res.output
        tracks[name] = pq.read_table(tmp_path / name / f"{trace.trace_id}.parquet")
    assert res.exit_code == 1 and "quiet: no waypoint to start from and no Wi-Fi or BLE fix; " \
        "give a start position" in res.output
    assert "recoveries ->" in res.output  # no "error at its waypoints": it has none
    assert tracks["plan"].column_names == tracks["trace"].column_names
    for column in ("t_ms", "x_m", "y_m"):
        np.testing.assert_array_equal(tracks["plan"].column(column).to_numpy(),
                                      tracks["trace"].column(column).to_numpy())
    res = runner.invoke(main, ["localize", bundles, str(plan), "-o", str(tmp_path / "given"),
                               "--no-plot", "--method", "pdr", "--start", "10,10"])
    assert res.exit_code == 0 and "quiet: " in res.output and "start given" in res.output
    scored = runner.invoke(main, ["evaluate", bundles, str(plan), "--method", "pdr"])
    assert "(walk quiet): no waypoints, skipped" in scored.output
    assert "no walk was evaluated" in scored.output
    # a sensor CSV given alone is such a walk, its radio logs found beside it by name (it
    # was read as a trace file: "expected 'timestamp<TAB>TYPE...'")
    log = plan.parent / "logs" / f"{trace.trace_id}.csv"
    res = runner.invoke(main, ["localize", bundles, str(log), "-o", str(tmp_path / "csv"),
                               "--no-plot", "--method", "indoormap"])
    assert res.exit_code == 0 and "start first Wi-Fi fix" in res.output, res.output
    alone = pq.read_table(tmp_path / "csv" / f"{trace.trace_id}.parquet")
    # the same track but for the phone's RSSI calibration (a log alone names no phone model)
    xy = {name: np.column_stack([t.column("x_m").to_numpy(), t.column("y_m").to_numpy()])
          for name, t in (("alone", alone), ("plan", tracks["plan"]))}
    apart = np.hypot(*(xy["alone"] - xy["plan"]).T)
    assert len(apart) == len(tracks["plan"]) and np.median(apart) < 1.0
    # auto's guided filter is told from the plain one in the written track (both said
    # method: indoormap)
    res = runner.invoke(main, ["localize", bundles, str(log), "-o", str(tmp_path / "auto"),
                               "--no-plot"])
    meta = pq.read_table(tmp_path / "auto" / f"{trace.trace_id}.parquet").schema.metadata
    assert (meta[b"method"], meta[b"ran"]) == (b"indoormap", b"indoormap guided by align")
    assert meta[b"auto"].startswith(b"the magnetic map's held-out 5 m change correlation")
    assert alone.schema.metadata[b"ran"] == b"indoormap" and b"auto" not in \
        alone.schema.metadata
    # without scans nor a floor in a header, the floor's bundle is given
    res = runner.invoke(main, ["localize", bundles, str(plan.parent / "logs" / "quiet.csv"),
                               "-o", str(tmp_path / "csv"), "--no-plot", "--start", "10,10"])
    assert res.exit_code == 1 and "give its floor's bundle" in res.output
    res = runner.invoke(main, ["localize", str(built / "F1"),
                               str(plan.parent / "logs" / "quiet.csv"), "-o",
                               str(tmp_path / "csv"), "--no-plot", "--start", "10,10"])
    assert res.exit_code == 0 and "quiet: " in res.output


def test_errors_at_paced_waypoint_times_say_so(truth_bundles, tmp_path):  # noqa: F811
    """A walk plan with start_ms and end_ms only has waypoint times spread at a steady pace,
    not clicks: localize and evaluate scored against them without a word, so a walker's
    pause read as the localizer's error. Both say it now; vertex times say nothing."""
    import json

    plan = _as_walk_plan(min(F1_WALKS.glob("*.txt.gz")), tmp_path / "plan")
    doc = json.loads(plan.read_text())
    props = doc["features"][0]["properties"]
    times = props.pop("vertex_times_ms")
    props.update(start_ms=times[0], end_ms=times[-1])
    paced = tmp_path / "plan" / "paced.geojson"
    paced.write_text(json.dumps(doc))
    bundles, runner = str(truth_bundles["F1"].parent), CliRunner()
    for path, said in ((plan, False), (paced, True)):
        res = runner.invoke(main, ["localize", bundles, str(path), "-o",
                                   str(tmp_path / path.stem), "--no-plot", "--method", "pdr",
                                   "--start", "waypoint"])
        assert res.exit_code == 0, res.output
        assert ("m (waypoint times at a steady pace) ->" in res.output) == said
        res = runner.invoke(main, ["evaluate", bundles, str(path), "--method", "pdr"])
        assert res.exit_code == 0, res.output
        assert ("note: 1 of the 1 walks give start_ms and end_ms, not vertex times: their "
                "waypoint times are spread at a steady pace" in res.output) == said


def test_walk_plans_are_walks_to_localize_and_evaluate(truth_bundles, tmp_path):  # noqa: F811
    """A walk of a walk plan (indoormap's walk-line format, which ``ingest`` and ``build``
    take) is localized and scored like the trace it was written from; before, ``localize``
    and ``evaluate`` found no trace file in it."""
    walk = min(F1_WALKS.glob("*.txt.gz"))
    plan = _as_walk_plan(walk, tmp_path / "plan")
    bundles = str(truth_bundles["F1"].parent)
    tracks = {}
    for name, path in (("trace", walk), ("plan", plan)):
        res = CliRunner().invoke(main, ["localize", bundles, str(path), "-o",
                                        str(tmp_path / name), "--no-plot", "--method", "pdr",
                                        "--start", "waypoint"])
        assert res.exit_code == 0, res.output
        assert "steps on" in res.output and "(F1) by pdr" in res.output
        tracks[name] = pq.read_table(tmp_path / name / f"{walk.name.split('.')[0]}.parquet")
    for column in ("t_ms", "x_m", "y_m"):  # the same walk, the same track
        np.testing.assert_array_equal(tracks["plan"].column(column).to_numpy(),
                                      tracks["trace"].column(column).to_numpy())
    scored = CliRunner().invoke(main, ["evaluate", bundles, str(tmp_path / "plan"),
                                       "--method", "pdr"])
    assert scored.exit_code == 0, scored.output
    assert "at the waypoints of 1 walk(s)" in scored.output
    # a walk plan that cannot be read is one failed walk, named, and the others go on
    (tmp_path / "bad.geojson").write_text('{"type": "FeatureCollection", "features": []}')
    both = CliRunner().invoke(main, ["evaluate", bundles, str(tmp_path / "bad.geojson"),
                                     str(walk), "--method", "pdr"])
    assert both.exit_code == 1 and "bad.geojson: walk plan has no features" in both.output
    assert "1 failure(s) in 2 walk(s)" in both.output
    # one walk of a plan failing its checks (its vertex times an hour off its log's) fails
    # alone, named; before, the plan's other walks were lost with it
    import json

    doc = json.loads(plan.read_text())
    bad = json.loads(json.dumps(doc["features"][0]))
    bad["properties"].update(walk_id="shifted", vertex_times_ms=[
        t + 3_600_000 for t in bad["properties"]["vertex_times_ms"]])
    # and so does one whose sensor log is missing (the logs are read walk by walk)
    lost = json.loads(json.dumps(doc["features"][0]))
    lost["properties"].update(walk_id="lost", sensor_log="gone.csv")
    doc["features"] += [bad, lost]
    plan.write_text(json.dumps(doc))
    two = CliRunner().invoke(main, ["localize", bundles, str(plan), "-o", str(tmp_path / "two"),
                                    "--no-plot", "--method", "pdr", "--start", "waypoint"])
    assert two.exit_code == 1 and "2 failure(s) in 3 walk(s)" in two.output
    assert f"{plan} (walk shifted)" in two.output
    assert f"{plan} (walk lost)" in two.output and "sensor log 'gone.csv' not" in two.output
    assert (tmp_path / "two" / f"{walk.name.split('.')[0]}.parquet").is_file()


def test_walk_ids_that_are_no_file_names_or_repeat_stay_in_the_output_folder(
        truth_bundles, tmp_path):  # noqa: F811
    """A walk plan's ids name localize's output files: ``../../escape`` wrote two folders
    above ``-o`` and ``line 7/a`` made a subfolder; an id given twice in one plan ran twice,
    the second track replacing the first's (exit 0). Now the ids are made safe names and
    the second walk of an id is refused, named by its feature."""
    import json

    walk = min(F1_WALKS.glob("*.txt.gz"))
    plan = _as_walk_plan(walk, tmp_path / "plan")
    doc = json.loads(plan.read_text())
    feature = doc["features"][0]
    doc["features"] = [json.loads(json.dumps(feature)) for _ in range(4)]
    for f, walk_id in zip(doc["features"], ["../../escape", "line 7/a", "twice", "twice"]):
        f["properties"]["walk_id"] = walk_id
    plan.write_text(json.dumps(doc))
    out = tmp_path / "deep" / "er" / "out"
    res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), str(plan), "-o",
                                    str(out), "--method", "pdr", "--start", "waypoint",
                                    "--format", "csv"])
    assert res.exit_code == 1, res.output
    assert f"{plan} (walk twice, feature 3): trace id twice is also {plan} (walk twice, " \
        "feature 2)'s in this run" in res.output
    written = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*.csv")
                     if "plan" not in p.parts)
    assert written == ["deep/er/out/_._.._escape-" + _sha8("../../escape") + ".csv",
                       "deep/er/out/line_7_a-" + _sha8("line 7/a") + ".csv",
                       "deep/er/out/twice.csv"]
    assert sorted(p.name for p in out.glob("*.png")) == [w.replace(".csv", ".png") for w in
                                                          (p.rsplit("/", 1)[1] for p in written)]
    track = pd.read_csv(out / f"line_7_a-{_sha8('line 7/a')}.csv")
    assert set(track["trace_id"]) == {"line 7/a"}  # the table keeps the walk's own id


def _sha8(text: str) -> str:
    import hashlib

    return hashlib.sha256(text.encode()).hexdigest()[:8]


def test_a_walk_without_magnetometer_is_localized_by_auto_with_the_alignment(
        truth_bundles, tmp_path):  # noqa: F811
    """A phone that logged no magnetometer: the steps' summary refused the walk ("no
    magnetometer stream"), and ``auto`` would have picked the filter, which needs the field;
    ``auto`` runs the alignment and says why, and the magnetic methods fail alone."""
    import gzip

    walk = min(F1_WALKS.glob("*.txt.gz"))
    with gzip.open(walk, "rt") as f:
        kept = [line for line in f if "TYPE_MAGNETIC_FIELD" not in line]
    no_mag = tmp_path / "walks" / "nomag.txt"
    no_mag.parent.mkdir()
    no_mag.write_text("".join(kept))
    bundles = str(truth_bundles["F1"].parent)
    res = CliRunner().invoke(main, ["localize", bundles, str(no_mag), "-o", str(tmp_path / "o"),
                                    "--no-plot", "--start", "waypoint"])
    assert res.exit_code == 0, res.output
    assert "by auto: align, as the walk has no magnetometer values" in res.output
    scored = CliRunner().invoke(main, ["evaluate", bundles, str(no_mag), "--start", "waypoint",
                                       "--method", "auto,indoormap,pf_no_mag"])
    assert scored.exit_code == 1  # indoormap cannot run it, and says what can
    assert "method indoormap needs the magnetic field (align, pf_no_mag" in scored.output
    rows = {line.split()[0] + (" " + line.split()[1] if line.startswith("auto") else ""):
            line.split() for line in scored.output.splitlines()
            if line.startswith(("auto", "indoormap", "pf_no_mag"))}
    n = str(len(waypoints_of(read_trace(no_mag))[0]))
    assert rows["auto (align)"][2] == n and float(rows["auto (align)"][3]) < 3.0  # median, m
    assert rows["indoormap"][1] == "0" and rows["pf_no_mag"][1] == n


def test_overwrite_replaces_every_earlier_output_of_a_walk(truth_bundles, tmp_path):  # noqa: F811
    """A walk's outputs are its table in either format and its plot: a run in the other
    format is refused without --overwrite (the earlier run's table would stay beside this
    run's), and with it the earlier table and plot go; before, ``--format csv --overwrite``
    left the earlier ``.parquet`` and ``.png`` beside the new ``.csv``."""
    walk = min(F1_WALKS.glob("*.txt.gz"))
    tid, out = walk.name.split(".")[0], tmp_path / "out"
    args = ["localize", str(truth_bundles["F1"]), str(walk), "-o", str(out), "--method", "pdr",
            "--start", "waypoint"]
    assert CliRunner().invoke(main, args).exit_code == 0
    assert sorted(p.name for p in out.iterdir()) == [f"{tid}.parquet", f"{tid}.png"]
    csv = args + ["--format", "csv", "--no-plot"]
    refused = CliRunner().invoke(main, csv)
    assert refused.exit_code == 1 and f"{tid}.parquet exists; pass --overwrite" in refused.output
    res = CliRunner().invoke(main, csv + ["--overwrite"])
    assert res.exit_code == 0, res.output
    assert f"(removed the earlier run's {tid}.parquet, {tid}.png)" in res.output
    assert [p.name for p in out.iterdir()] == [f"{tid}.csv"]
    smoothed = CliRunner().invoke(main, args + ["--smooth", "--method", "align", "--no-plot"])
    assert smoothed.exit_code == 0, smoothed.output  # the smoothed track is another output
    assert sorted(p.name for p in out.iterdir()) == [f"{tid}.csv", f"{tid}.smoothed.parquet"]


def test_a_trace_and_a_walk_plan_with_one_id_keep_the_trace_as_ingest_does(
        truth_bundles, tmp_path):  # noqa: F811
    """``ingest`` takes a run's trace files before its walk plans, and refuses a later input
    with a trace id already seen; ``localize`` refused the one sorting later by path, so with
    the plan's folder sorting first it kept the plan's walk where ingest kept the trace."""
    import json

    from survey.ingest import ingest

    walk = min(F1_WALKS.glob("*.txt.gz"))
    other = sorted(F1_WALKS.glob("*.txt.gz"))[1]
    plan = _as_walk_plan(other, tmp_path / "a_plan")  # the other walk, under walk's id
    doc = json.loads(plan.read_text())
    tid = walk.name.split(".")[0]
    doc["features"][0]["properties"]["walk_id"] = tid
    plan.write_text(json.dumps(doc))
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / walk.name).write_bytes(walk.read_bytes())
    inputs = [str(tmp_path / "a_plan"), str(tmp_path / "b")]
    summary = ingest(inputs, tmp_path / "store")
    kept = [o.path for o in summary.outcomes if o.status != "failed"]
    assert kept == [str(tmp_path / "b" / walk.name)]
    res = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), *inputs, "-o",
                                    str(tmp_path / "out"), "--method", "pdr", "--no-plot",
                                    "--start", "waypoint"])
    assert res.exit_code == 1
    assert f"{plan} (walk {tid}): trace id {tid} is also {tmp_path / 'b' / walk.name}'s" \
        in res.output
    alone = CliRunner().invoke(main, ["localize", str(truth_bundles["F1"]), str(walk), "-o",
                                      str(tmp_path / "alone"), "--method", "pdr", "--no-plot",
                                      "--start", "waypoint"])
    assert alone.exit_code == 0, alone.output  # what was written is the trace's track
    assert (tmp_path / "out" / f"{tid}.parquet").read_bytes() == \
        (tmp_path / "alone" / f"{tid}.parquet").read_bytes()


def test_a_walk_whose_compass_is_turned_is_said_and_turned_back(built, monkeypatch):  # noqa: F811
    """The command line turns the compass of a walk whose step track fits its fixes only
    turned (a phone held in landscape: every heading 90 deg off), says so, and keeps it as
    logged with --compass as-logged."""
    import dataclasses

    import survey.step_summaries as summaries

    plain = summaries.step_summaries
    monkeypatch.setattr(summaries, "step_summaries", lambda trace: dataclasses.replace(
        s := plain(trace), compass_deg=(s.compass_deg + 90) % 360))
    walk = sorted((SAMPLE / "F1" / "path_data_files").glob("*.txt.gz"))[0]
    medians = {}
    for compass in ("auto", "as-logged"):
        res = CliRunner().invoke(main, ["evaluate", str(built), str(walk), "--method", "align",
                                        "--compass", compass])
        assert res.exit_code == 0, res.output
        said = re.search(r"radio fixes only turned (\d+) deg anticlockwise of its compass.*; "
                         r"(its compass is turned so|kept as logged)", res.output)
        assert said and 80 <= int(said.group(1)) <= 100, res.output
        assert said.group(2) == ("its compass is turned so" if compass == "auto"
                                 else "kept as logged")
        medians[compass] = float(re.search(r"^align\s+\d+\s+([\d.]+)", res.output, re.M)[1])
    assert medians["as-logged"] > 3 * medians["auto"], medians


def test_the_cdf_plot_says_when_the_map_has_seen_the_walks(built, tmp_path,  # noqa: F811
                                                            monkeypatch):
    """The terminal warned that the map had seen the walks; the plot, which outlives the
    terminal, did not (a sample's 0.55 m median for walks the map was built from, 2.06 m
    held out)."""
    import localize.plots

    titles = []
    monkeypatch.setattr(localize.plots, "plot_cdfs",
                        lambda path, errors, title="": titles.append(title) or True)
    walks = sorted((SAMPLE / "F1" / "path_data_files").glob("*.txt.gz"))[:2]
    res = CliRunner().invoke(main, ["evaluate", str(built), *map(str, walks), "--method", "pdr",
                                    "--plot-file", str(tmp_path / "cdf.png")])
    assert res.exit_code == 0, res.output
    assert titles == [f"{built.name}: 2 walk(s), start auto; 2 of the walks seen by the map "
                      "(errors better than unseen walks')"]


def test_evaluate_says_when_a_walk_starts_from_the_truth(built, tmp_path):  # noqa: F811
    """A walk without radio starts at its first waypoint (--start auto's fallback): its
    errors start from the truth, better than a user's would; evaluate said nothing."""
    import gzip

    walk = sorted((SAMPLE / "F1" / "path_data_files").glob("*.txt.gz"))[0]
    text = gzip.decompress(walk.read_bytes()).decode()
    quiet = tmp_path / "no_radio.txt"
    quiet.write_text("\n".join(line for line in text.splitlines()
                               if "\tTYPE_WIFI\t" not in line and "\tTYPE_BEACON\t" not in line))
    res = CliRunner().invoke(main, ["evaluate", str(built), str(quiet), "--method", "pdr"])
    assert res.exit_code == 0, res.output
    assert re.search(r"note: \S+: start first waypoint \(no .* fix in the walk\): its errors "
                     r"start from the truth", res.output), res.output
    res = CliRunner().invoke(main, ["evaluate", str(built), str(quiet), "--method", "pdr",
                                    "--start", "waypoint"])  # asked for: no note
    assert res.exit_code == 0 and "start from the truth" not in res.output
