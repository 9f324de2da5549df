"""Traces refused whole (docs/trace_format.md, "Files refused whole"): two traces joined into
one file (a header key given again with another value), and the resource limits checked
before memory is taken: not a regular file (FIFO, link to /dev/zero), over the size limit on
disk, a gzip bomb inflated in bounded steps."""

from __future__ import annotations

import gzip
import os
import subprocess
import sys
import textwrap
import threading
import time
import tracemalloc
import zlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

import survey.trace_bytes as trace_bytes
from survey.cli import main
from survey.errors import SurveyFormatError
from survey.trace_bytes import read_trace_bytes, wide_encoding
from survey.trace_header import parse_header
from survey.trace_reader import ReadFailure, find_trace_files, iter_traces, read_trace
from survey.trace_writer import render_trace, write_trace

from factories import small_trace

MB = 1024**2


# --------------------------------------------------------------------------------------------
# Two traces joined into one file


def _second_walk(change: str):
    b = small_trace(n=80, seed=1, trace_id="walk0002")
    if change == "floor":  # same start time: the conflict is on the SiteID/FloorName line
        b.header.floor_name, b.header.floor_id = "F2", "floor_a2"
    else:  # another walk: its start time differs first
        b.header.start_ms += 3_600_000
        b.header.end_ms += 3_600_000
    return b


@pytest.mark.parametrize("suffix", [".txt", ".txt.gz"])
@pytest.mark.parametrize("change, line_in_b, key", [("floor", 2, "FloorId"),
                                                     ("walk", 1, "startTime")])
def test_two_traces_joined_are_refused_in_both_modes_naming_the_line(
        tmp_path, suffix, change, line_in_b, key):
    """``cat a.txt.gz b.txt.gz > c.txt.gz`` (two gzip members) or two plain texts joined: the
    second header would relabel the first walk's rows (F1 data stored as F2), so the file is
    refused in strict and lenient mode, at the second header's first conflicting line."""
    a = small_trace(n=60)
    pa = write_trace(tmp_path / f"a{suffix}", a)
    pb = write_trace(tmp_path / f"b{suffix}", _second_walk(change))
    joined = tmp_path / f"c{suffix}"
    joined.write_bytes(pa.read_bytes() + pb.read_bytes())
    line = render_trace(a).count("\n") + line_in_b
    for strict in (False, True):
        with pytest.raises(SurveyFormatError, match=rf"c{suffix}:{line}: header {key} is ") as ei:
            read_trace(joined, strict=strict)
        assert ei.value.reason == "header_conflict" and ei.value.line == line
        assert ei.value.path == str(joined)
    # lenient batches: a failure for that file, the files around it still read
    items = list(iter_traces([pa, joined, pb]))
    assert [type(i).__name__ for i in items] == ["Trace", "ReadFailure", "Trace"]
    assert items[1].error.reason == "header_conflict" and items[1].path == str(joined)
    with pytest.raises(SurveyFormatError, match=rf"c{suffix}:{line}: header"):
        list(iter_traces([pa, joined, pb], strict=True))
    # ingest reports the file failed with that message and stores the others
    res = CliRunner().invoke(main, ["ingest", str(pa), str(joined), "--store",
                                    str(tmp_path / "store")])
    assert res.exit_code == 1, res.output
    assert f"c{suffix}:{line}: header {key} is " in res.output


def test_a_conflicting_header_is_reported_before_later_bad_lines_in_strict_mode(tmp_path):
    a, b = small_trace(n=60), _second_walk("floor")
    text = render_trace(a) + render_trace(b) + "123\tTYPE_WIFI\tx\n"
    p = tmp_path / "c.txt"
    p.write_text(text)
    with pytest.raises(SurveyFormatError) as ei:
        read_trace(p, strict=True)
    assert ei.value.reason == "header_conflict"


def test_a_header_repeated_with_the_same_value_is_read(tmp_path):
    """The same key with the same value again (a header line written twice, white space
    around a value), and two sensors of one type, are fine."""
    a = small_trace(n=60)
    lines = render_trace(a).splitlines()
    head = [ln for ln in lines if ln.startswith("#") and "endTime" not in ln]
    extra = [head[1], head[0].replace("startTime:", "startTime: "),
             "#\ttype:1\tname:Acc2\tversion:2\tvendor:W\tresolution:0.01\tpower:0.3"
             "\tmaximumRange:78"]
    p = tmp_path / "rep.txt"
    p.write_text("\n".join(lines[:len(head)] + extra + lines[len(head):]) + "\n")
    for strict in (False, True):
        t = read_trace(p, strict=strict)
        assert (t.header.site_id, t.header.floor_name, t.header.start_ms) == (
            "site_a", "F1", a.header.start_ms)
        assert [s.name for s in t.header.sensors] == ["Acc", "Acc2"]
        assert t.report.header_lines == len(head) + len(extra) + 1
    # one file twice (same header): read as the file once, its repeated rows dropped
    pg = write_trace(tmp_path / "a.txt.gz", a)
    twice = tmp_path / "twice.txt.gz"
    twice.write_bytes(pg.read_bytes() * 2)
    once, doubled = read_trace(pg, strict=True), read_trace(twice, strict=True)
    assert len(once.ble) and len(once.waypoints) and len(once.wifi)
    for table in ("sensors", "wifi", "ble", "waypoints"):
        pd.testing.assert_frame_equal(getattr(doubled, table), getattr(once, table))
    assert doubled.report.dropped == {"duplicate_timestamp": len(once.sensors),
                                      "duplicate_bssid_in_scan": len(once.wifi),
                                      "duplicate_beacon": len(once.ble),
                                      "duplicate_waypoint": len(once.waypoints)}


def test_a_key_given_twice_on_one_line_with_two_values_is_refused():
    with pytest.raises(SurveyFormatError, match=r"w.txt:7: header SiteID is 'b' here but 'a' "
                                                r"on the same line") as ei:
        parse_header([b"#\tSiteID:a\tSiteID:b"], path="w.txt", line_numbers=[7])
    assert ei.value.reason == "header_conflict"
    assert parse_header([b"#\tSiteID:a\tSiteID: a "]).site_id == "a"


def test_real_ilc_headers_have_no_conflict(ilc_floor):
    for p in sorted((ilc_floor / "path_data_files").glob("*.txt.gz"))[:20]:
        with gzip.open(p) as fh:
            parse_header([ln.rstrip(b"\r\n") for ln in fh if ln.startswith(b"#")], path=str(p))


# --------------------------------------------------------------------------------------------
# Resource limits: bounded inflating


class _Recorder:
    """Wraps the decompressor ``trace_bytes`` uses, recording each call's ``max_length`` and
    output size."""

    def __init__(self, monkeypatch):
        self.calls: list[tuple[int, int]] = []
        real = trace_bytes._zlib
        recorder = self

        class Dec:
            def __init__(self, *args, **kwargs):
                self._d = real.decompressobj(*args, **kwargs)

            def decompress(self, data, max_length=0):
                out = self._d.decompress(data, max_length)
                recorder.calls.append((max_length, len(out)))
                return out

            def __getattr__(self, name):
                return getattr(self._d, name)

        class Module:
            error = real.error

            @staticmethod
            def decompressobj(*args, **kwargs):
                return Dec(*args, **kwargs)

        monkeypatch.setattr(trace_bytes, "_zlib", Module)


def _bomb(path, n_bytes: int):
    c = zlib.compressobj(9, zlib.DEFLATED, 31)
    zeros = bytes(MB)
    with open(path, "wb") as fh:
        for _ in range(n_bytes // MB):
            fh.write(c.compress(zeros))
        fh.write(c.flush())
    return path


def _peak(call) -> tuple[int, object]:
    tracemalloc.start()
    try:
        try:
            result = call()
        except SurveyFormatError as err:
            result = err
        return tracemalloc.get_traced_memory()[1], result
    finally:
        tracemalloc.stop()


def test_a_gzip_bomb_is_refused_within_a_small_budget(tmp_path):
    bomb = _bomb(tmp_path / "bomb.txt.gz", 50 * MB)
    peak, err = _peak(lambda: read_trace_bytes(bomb, max_bytes=MB))
    assert isinstance(err, SurveyFormatError) and err.reason == "too_large"
    assert peak < 4 * MB + 3 * MB


def test_a_gzip_bomb_is_inflated_in_bounded_steps_and_measured_not_kept(tmp_path, monkeypatch):
    """Under a limit larger than the memory one wants to spend: each step inflates at most
    ``_OUT_STEP`` bytes, and a stream inflating far more than real traces do is measured
    (its text thrown away) before anything is kept, so the refusal costs about
    ``_SUSPECT_BYTES``, not the limit."""
    bomb = _bomb(tmp_path / "bomb.txt.gz", 50 * MB)
    monkeypatch.setattr(trace_bytes, "_OUT_STEP", MB // 2)
    monkeypatch.setattr(trace_bytes, "_SUSPECT_BYTES", 2 * MB)
    rec = _Recorder(monkeypatch)
    peak, err = _peak(lambda: read_trace_bytes(bomb, max_bytes=40 * MB))
    assert isinstance(err, SurveyFormatError) and err.reason == "too_large"
    assert "decompresses to over 41943040 bytes" in str(err)
    assert max(m for m, _ in rec.calls) <= MB // 2
    assert peak < 6 * MB, peak  # not the 40 MB the limit allows


def test_a_very_compressible_text_under_the_limit_is_read_whole(tmp_path, monkeypatch):
    text = b"1600000000000\tTYPE_WAYPOINT\t1.5\t2.5\n" * 200_000  # 7 MB, over 500 x smaller
    p = tmp_path / "walk.txt.gz"
    p.write_bytes(gzip.compress(text[: len(text) // 2]) + gzip.compress(text[len(text) // 2:])
                  + bytes(100))
    monkeypatch.setattr(trace_bytes, "_OUT_STEP", MB // 2)
    monkeypatch.setattr(trace_bytes, "_SUSPECT_BYTES", 2 * MB)
    rec = _Recorder(monkeypatch)
    assert read_trace_bytes(p, strict=True) == (text, None)
    inflated = sum(n for _, n in rec.calls)  # the suspect part, all measured, all kept
    assert 2 * len(text) < inflated <= 2 * len(text) + 2 * MB + MB // 2
    assert read_trace_bytes(p, max_bytes=len(text)) == (text, None)
    with pytest.raises(SurveyFormatError, match="decompresses to over"):
        read_trace_bytes(p, max_bytes=len(text) - 1)


@pytest.mark.parametrize("steps", [(7, 13), (1, 1), (4096, 100_000)])
def test_small_steps_give_the_same_text_and_notes(tmp_path, monkeypatch, steps):
    """Members, zero padding, trailing garbage and a cut stream read the same whatever the
    step sizes (a member boundary or the end of input inside a step)."""
    a = render_trace(small_trace(n=200)).encode()
    b = render_trace(small_trace(n=100, seed=2)).encode()
    ga, gb = gzip.compress(a, mtime=0), gzip.compress(b, mtime=0)
    cases = {"two": ga + gb, "padded": ga + gb + bytes(300), "garbage": ga + b"junk\n",
             "magic": ga + b"\x1f\x8b", "cut": ga + gb[: len(gb) // 2],
             "empty_members": gzip.compress(b"") + ga + gzip.compress(b"")}
    expected = {}
    for name, data in cases.items():
        p = tmp_path / f"{name}.txt.gz"
        p.write_bytes(data)
        expected[name] = read_trace_bytes(p)
    assert expected["two"] == expected["padded"] == (a + b, None)
    assert expected["garbage"] == (a, "trailing garbage after gzip stream")
    assert expected["magic"] == (a, "truncated gzip stream")
    assert expected["cut"][1] == "truncated gzip stream" and expected["cut"][0].startswith(a)
    assert expected["empty_members"] == (a, None)
    monkeypatch.setattr(trace_bytes, "_IN_STEP", steps[0])
    monkeypatch.setattr(trace_bytes, "_OUT_STEP", steps[1])
    for name in cases:
        got = read_trace_bytes(tmp_path / f"{name}.txt.gz")
        if name == "cut":  # a cut stream may give a few more bytes of its readable prefix
            assert got[1] == expected[name][1] and got[0].startswith(expected[name][0])
        else:
            assert got == expected[name], name


# --------------------------------------------------------------------------------------------
# Resource limits: size on disk, regular files only


def test_a_plain_file_over_the_limit_is_refused_without_reading_it(tmp_path):
    sparse = tmp_path / "big.txt"
    with open(sparse, "wb") as fh:
        fh.truncate(10 * MB)
    peak, err = _peak(lambda: read_trace_bytes(sparse, max_bytes=MB))
    assert isinstance(err, SurveyFormatError) and err.reason == "too_large"
    assert f"file is {10 * MB} bytes, over the {MB}-byte limit" in str(err)
    assert peak < MB // 4, peak
    gz = tmp_path / "big.txt.gz"  # a compressed file over the limit is not read either
    with open(gz, "wb") as fh:
        fh.write(b"\x1f\x8b\x08\x00")
        fh.truncate(10 * MB)
    peak, err = _peak(lambda: read_trace_bytes(gz, max_bytes=MB))
    assert isinstance(err, SurveyFormatError) and err.reason == "too_large"
    assert peak < MB // 4, peak


def test_a_file_growing_while_read_is_not_read_past_the_limit(tmp_path, monkeypatch):
    """The size looked at is where reading is expected to end; a file grown since is read on,
    in steps, and refused as soon as it passes the limit."""
    data = b"1\tTYPE_WAYPOINT\t1\t2\n" * 150_000  # 3 MB
    p = tmp_path / "growing.txt"
    p.write_bytes(data)
    ino = p.stat().st_ino
    real_stat, real_fstat = os.stat, os.fstat

    def small(st):  # as if the file had been 100 bytes when looked at
        if st.st_ino != ino:
            return st
        return os.stat_result((st.st_mode, st.st_ino, st.st_dev, st.st_nlink, st.st_uid,
                               st.st_gid, 100, st.st_atime, st.st_mtime, st.st_ctime))

    monkeypatch.setattr(trace_bytes.os, "stat", lambda *a, **k: small(real_stat(*a, **k)))
    monkeypatch.setattr(trace_bytes.os, "fstat", lambda fd: small(real_fstat(fd)))
    assert read_trace_bytes(p) == (data, None)
    peak, err = _peak(lambda: read_trace_bytes(p, max_bytes=MB // 2))
    assert isinstance(err, SurveyFormatError) and err.reason == "too_large"
    assert "grew past the 524288-byte limit while read" in str(err)
    assert peak < MB, peak  # not the 3 MB of the file


_CHILD = textwrap.dedent("""
    import resource, sys, time
    resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))  # old code read /dev/zero on
    from survey.errors import SurveyFormatError
    from survey.trace_bytes import read_trace_bytes
    for p in sys.argv[1:]:
        t = time.perf_counter()
        try:
            read_trace_bytes(p)
            print("read", p)
        except SurveyFormatError as err:
            print(err.reason, round(time.perf_counter() - t, 3), err)
""")


@pytest.mark.skipif(not hasattr(os, "mkfifo") or not os.path.exists("/dev/zero"),
                    reason="needs FIFOs and /dev/zero")
def test_a_fifo_or_a_link_to_dev_zero_is_refused_at_once(tmp_path):
    """Reading either would block (a FIFO without a writer) or never end (/dev/zero): both
    are refused before they are opened. Run in a child process with a timeout so that a
    regression fails instead of hanging the test run."""
    fifo = tmp_path / "fifo.txt"
    os.mkfifo(fifo)
    zero = tmp_path / "zero.txt"
    zero.symlink_to("/dev/zero")
    res = subprocess.run([sys.executable, "-c", _CHILD, str(fifo), str(zero)],
                         capture_output=True, text=True, timeout=120)
    lines = res.stdout.splitlines()
    assert res.returncode == 0 and len(lines) == 2, res.stdout + res.stderr
    for line, p in zip(lines, (fifo, zero)):
        reason, seconds, message = line.split(" ", 2)
        assert reason == "not_regular" and float(seconds) < 1, line
        assert message.startswith(f"{p}: not a regular file")
    # named on the command line: refused by name before anything opens it (the ingest
    # hashes files first); a folder holding them reads its regular files only
    for p in (fifo, zero):
        with pytest.raises(SurveyFormatError, match="not a regular file") as ei:
            find_trace_files([p])
        assert ei.value.reason == "not_regular"
    good = write_trace(tmp_path / "walk.txt", small_trace(n=20))
    assert find_trace_files([tmp_path]) == [good]
    t = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", "from survey.cli import main; main()", "ingest",
                          str(zero), "--store", str(tmp_path / "store")],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 1 and "zero.txt: not a regular file" in res.stderr + res.stdout
    assert time.perf_counter() - t < 60


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_lenient_iter_traces_reports_a_fifo_and_goes_on(tmp_path):
    good = write_trace(tmp_path / "walk.txt", small_trace(n=20))
    fifo = tmp_path / "fifo.txt"
    os.mkfifo(fifo)
    # a reader blocked on the FIFO (a regression) is set free after 30 s by a writer that
    # opens and closes it, so the test fails instead of hanging
    unblock = threading.Timer(30, lambda: open(fifo, "wb").close())
    unblock.daemon = True
    unblock.start()
    try:
        items = list(iter_traces([fifo, good]))
    finally:
        unblock.cancel()
    assert isinstance(items[0], ReadFailure) and items[0].error.reason == "not_regular"
    assert items[1].trace_id == "walk"



_SWAP_CHILD = textwrap.dedent("""
    import os, sys
    import survey.ingest as ingest_module
    from survey.errors import SurveyFormatError
    from survey.publish import file_sha256
    from survey.regular_files import NotRegularFile
    good, swapped, fifo, store = sys.argv[1:]
    try:
        file_sha256(fifo)
    except NotRegularFile as err:
        print("hash refused:", err)
    listed = ingest_module.find_inputs([good, swapped])
    os.replace(fifo, swapped)  # a FIFO in its place after the listing, before the hash
    ingest_module.find_inputs = lambda paths: listed
    summary = ingest_module.ingest([good, swapped], store)
    print(sorted((os.path.basename(o.path), o.status) for o in summary.outcomes))
    print([o.detail for o in summary.outcomes if o.status == "failed"][0])
    try:
        ingest_module.ingest([good, swapped], store + "2", strict=True)
    except SurveyFormatError as err:
        print("strict:", err.reason)
""")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_file_swapped_for_a_fifo_after_listing_fails_instead_of_blocking(tmp_path):
    """The ingest hashes each listed file before parsing it; a file replaced by a FIFO in
    between made the hash wait forever for a writer. Now the hash refuses it at once (a failed
    outcome, or the strict run's error) and the other files are stored. In a child process
    with a timeout, so that a regression fails instead of hanging the test run."""
    good = write_trace(tmp_path / "walk.txt", small_trace(n=20))
    swapped = write_trace(tmp_path / "other.txt", small_trace(n=20, seed=3, trace_id="other"))
    fifo = tmp_path / "fifo.txt"
    os.mkfifo(fifo)
    res = subprocess.run([sys.executable, "-c", _SWAP_CHILD, str(good), str(swapped),
                          str(fifo), str(tmp_path / "store")], capture_output=True, text=True,
                         timeout=120)
    lines = res.stdout.splitlines()
    assert res.returncode == 0 and len(lines) == 4, res.stdout + res.stderr
    assert lines[0] == f"hash refused: not a regular file: {fifo}"
    assert lines[1] == "[('other.txt', 'failed'), ('walk.txt', 'new')]"
    assert lines[2].startswith(f"{swapped}: not a regular file")
    assert lines[3] == "strict: not_regular"


def test_a_file_name_that_is_not_utf8_is_refused_by_name(tmp_path):
    """The name becomes the trace id: ingest and build crashed writing it to the store
    (UnicodeEncodeError), localize after all its work. Now a clear error, the name escaped."""
    sample = Path(__file__).resolve().parents[1] / "data" / "sample_site"  # conftest makes it
    src = min((sample / "F1" / "path_data_files").glob("*.txt.gz"))
    (tmp_path / "in").mkdir()
    bad = tmp_path / "in" / os.fsdecode(b"walk\xff\xfe.txt.gz")
    bad.write_bytes(src.read_bytes())
    with pytest.raises(SurveyFormatError, match=r"walk\\xff\\xfe.txt.gz: the path is not "
                                                r"valid UTF-8"):
        find_trace_files([tmp_path / "in"])
    res = CliRunner().invoke(main, ["ingest", str(tmp_path / "in"), "--store",
                                    str(tmp_path / "store")])
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert "the path is not valid UTF-8" in res.output
    folder = tmp_path / os.fsdecode(b"walks\xff")  # a good name in a bad folder
    folder.mkdir()
    bad.rename(folder / src.name)
    with pytest.raises(SurveyFormatError, match=r"walks\\xff/.*: the path is not valid"):
        find_trace_files([tmp_path])


def _chinese_named_trace_text() -> str:
    """A small trace's text whose first header line is the site's name in Chinese (as the
    real mall traces' second line is)."""
    trace = small_trace()
    trace.header.site_name = "杭州西溪银泰城"
    text = render_trace(trace)
    lines = text.splitlines(keepends=True)
    at = next(i for i, line in enumerate(lines) if "SiteName:" in line)
    return lines[at] + "".join(lines[:at] + lines[at + 1:])


@pytest.mark.parametrize("encoding, name, order", [
    ("utf-16", "UTF-16", "little"), ("utf-16-le", "UTF-16", "little"),
    ("utf-16-be", "UTF-16", "big"), ("utf-32", "UTF-32", "little"),
    ("utf-32-le", "UTF-32", "little"), ("utf-32-be", "UTF-32", "big")])
def test_a_utf16_or_32_trace_is_named_as_such(tmp_path, encoding, name, order):
    """A trace saved as UTF-16 (Windows "Unicode" text) or UTF-32, with or without a
    byte-order mark, gzipped or not, was read as UTF-8: every line a bad line, and the
    reason given was the first line's ("timestamp is not an integer of milliseconds"). The
    reason is the encoding, said in both modes, also when the text starts with a name in
    Chinese (no NUL beside those characters: a check of every one of the first 64 characters
    missed it) and for UTF-32 (its mark was said to be UTF-16's); UTF-8 text (with its own
    mark, or with the Chinese name first) still reads."""
    for text in (render_trace(small_trace()), _chinese_named_trace_text()):
        for file, data in (("a.txt", text.encode(encoding)),
                           ("b.txt.gz", gzip.compress(text.encode(encoding)))):
            (tmp_path / file).write_bytes(data)
            for strict in (False, True):
                with pytest.raises(SurveyFormatError, match=f"{name} text \\({order}-endian\\); "
                                   f"indoormap reads UTF-8: convert it \\(e.g. iconv -f {name} "
                                   "-t UTF-8\\)") as err:
                    read_trace_bytes(tmp_path / file, strict=strict)
                assert err.value.reason == "encoding" and file in str(err.value)
    (tmp_path / "c.txt").write_bytes(b"\xef\xbb\xbf" + render_trace(small_trace()).encode())
    (tmp_path / "d.txt").write_text(_chinese_named_trace_text(), encoding="utf-8")
    for file in ("c.txt", "d.txt"):
        assert len(read_trace(tmp_path / file).sensors) == len(small_trace().sensors)
    assert read_trace(tmp_path / "d.txt").header.site_name == "杭州西溪银泰城"


def test_wide_text_is_named_past_an_emoji_and_a_short_first_gzip_member(tmp_path):
    """UTF-32 without a mark whose name holds a character beyond U+FFFF (its second byte not
    NUL) was missed; a gzip file whose first member is a few bytes was judged by those."""
    text = _chinese_named_trace_text().replace("杭州", "杭州\U0001F600")
    assert wide_encoding(text.encode("utf-32-le")) == ("UTF-32", "little")
    assert wide_encoding(text.encode("utf-32-be")) == ("UTF-32", "big")
    data = text.encode("utf-16-le")
    (tmp_path / "m.txt.gz").write_bytes(gzip.compress(data[:20]) + gzip.compress(data[20:]))
    with pytest.raises(SurveyFormatError, match=r"UTF-16 text \(little-endian\)"):
        read_trace_bytes(tmp_path / "m.txt.gz")


def test_bytes_with_nuls_that_are_no_wide_text_are_not_called_so():
    """Only the NUL pattern of UTF-16 or UTF-32 names an encoding: NUL bytes alone (a file
    zero-filled by a crash), random bytes and short texts are left to the trace reader."""
    rng = np.random.default_rng(0)
    for data in (bytes(4096), rng.bytes(4096), "abcdefg".encode("utf-16-le"),
                 b"1\x00" * 10 + b"\x00" * 200):
        assert wide_encoding(data) is None
