"""The session-fit cache (processed/session_fits.json): an unchanged `process` takes the
calibration sessions' keys and fits from it instead of reading every walk's magnetometer
columns again, with results byte for byte those of a run without it."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import survey.process_store as ps
from survey.cli import main
from survey.ingest import ingest
from survey.magcal import MagCalResult
from survey.process_store import SESSION_CACHE, process_store, verify_session_cache
from survey.store import SurveyStore
from survey.trace_reader import read_trace
from survey.trace_writer import write_trace

SITE = Path(__file__).resolve().parents[1] / "data" / "sample_site"
F1 = sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))
MATE, B2 = F1[0], F1[2]  # a walk of the needs_fit walk's phone (SIM-A1), one of SIM-B2


def ok_fit(raw):
    """A session fit stubbed well conditioned (hard iron = the pooled mean). One function for
    this process and the killed ones: the cache's key holds the fitting code's source."""
    from survey.magcal import fit_ellipsoid

    return dataclasses.replace(fit_ellipsoid(raw), status="ok", reason="",
                               hard_iron_ut=raw.mean(axis=0),
                               soft_iron=np.eye(3) + raw.std(axis=0)[:, None] * 1e-3)


@pytest.fixture
def ok_fits(monkeypatch):
    """Session fits stubbed well conditioned (:func:`ok_fit`): the sample's flat-held walks
    give none, and a walk that needs one then has its field calibrated by it, so the cached
    fit's every bit shows in the processed samples."""
    monkeypatch.setattr(ps, "fit_ellipsoid", ok_fit)


@pytest.fixture
def mag_reads(monkeypatch):
    """Trace ids of the walks whose magnetometer columns are read (the session fit's reads)."""
    reads: list[str] = []
    real_part = SurveyStore.part

    def counting(self, name, row, columns=None):
        if name == "sensors" and columns == ps._MAG_COLUMNS:
            reads.append(getattr(row, "trace_id"))
        return real_part(self, name, row, columns)

    monkeypatch.setattr(SurveyStore, "part", counting)
    return reads


def _inputs(folder: Path) -> list[Path]:
    """A walk whose calibrated stream and raw one minus the phone's bias are implausible (it
    needs its session's fit; the bias, which puts it in MATE's session, is kept), MATE and
    a walk of another phone."""
    raw = read_trace(F1[1])
    for stream in ("magnetic_field", "magnetic_field_uncalibrated"):
        raw.sensors.loc[raw.sensors["stream"] == stream, ["x", "y", "z"]] *= 10
    write_trace(folder / "needs_fit.txt.gz", raw)
    return [folder / "needs_fit.txt.gz", MATE, B2]


def _changed_mate(folder: Path) -> Path:
    """MATE with every other sensor row: its session's pooled fit moves."""
    later = read_trace(MATE)
    later.sensors = later.sensors.iloc[::2].reset_index(drop=True)
    write_trace(folder / MATE.name, later)
    return folder / MATE.name


def _processed(store: Path, cache: bool = True) -> dict[str, bytes]:
    return {str(p.relative_to(store)): p.read_bytes()
            for p in sorted((store / "processed").rglob("*"))
            if p.is_file() and (cache or p.name != SESSION_CACHE)}


def test_an_unchanged_run_reads_no_magnetometer_column_and_gives_the_same_bytes(
        tmp_path, ok_fits, mag_reads):
    store = tmp_path / "s"
    ingest(_inputs(tmp_path / "in"), store)
    first = process_store(store)
    assert sorted(first.processed) == sorted(["needs_fit", MATE.name[:24], B2.name[:24]])
    assert len(mag_reads) == 3 and (store / "processed" / SESSION_CACHE).exists()
    cat = ps.processed_catalog(store).set_index("trace_id")
    assert cat.loc["needs_fit", "summary"]["calibration"] == "own-session-fit"
    before = _processed(store)
    mag_reads.clear()
    again = process_store(store)
    assert len(again.unchanged) == 3 and not again.processed and not again.warnings
    assert again.sessions == first.sessions
    assert process_store(store, floor="F1").unchanged and mag_reads == []
    assert _processed(store) == before  # the cache is not even rewritten
    # processed again from the cache alone: every file and the catalog the same bytes
    for p in (store / "processed").iterdir():
        if p.name != SESSION_CACHE:
            shutil.rmtree(p) if p.is_dir() else p.unlink()
    report = process_store(store)
    assert len(report.processed) == 3 and mag_reads == [] and not report.warnings
    assert _processed(store) == before


def test_a_changed_walk_refits_its_device_group_only(tmp_path, ok_fits, mag_reads):
    inputs = _inputs(tmp_path / "in")
    ingest(inputs, tmp_path / "a")
    process_store(tmp_path / "a")
    cache = (tmp_path / "a" / "processed" / SESSION_CACHE).read_bytes()
    later = _changed_mate(tmp_path / "later")
    ingest([later], tmp_path / "a")
    mag_reads.clear()
    report = process_store(tmp_path / "a")
    # the SIM-A1 walks are read again, not the SIM-B2 one (its entry is kept)
    assert sorted(mag_reads) == sorted(["needs_fit", MATE.name[:24]])
    assert sorted(report.processed) == sorted(["needs_fit", MATE.name[:24]])
    assert (tmp_path / "a" / "processed" / SESSION_CACHE).read_bytes() != cache
    # what a store that never had a cache gives for the same walks, byte for byte
    ingest([inputs[0], later, B2], tmp_path / "b")
    process_store(tmp_path / "b")
    assert _processed(tmp_path / "a") == _processed(tmp_path / "b")
    mag_reads.clear()
    assert len(process_store(tmp_path / "a").unchanged) == 3 and mag_reads == []


def _flip_a_fit_bit(path: Path) -> None:
    """Valid JSON, another fit: only the recorded sha256 tells."""
    doc = json.loads(path.read_text())
    fit = next(iter(doc["groups"]["SIM-A1"]["fits"].values()))
    h = bytearray(bytes.fromhex(fit["hard_iron_ut"]))
    h[0] ^= 1
    fit["hard_iron_ut"] = h.hex()
    path.write_text(json.dumps(doc))


def _short_array_with_its_sha(path: Path) -> None:
    """A fit array cut short, and the sha256 recorded for it: the structure checks tell."""
    doc = json.loads(path.read_text())
    fit = next(iter(doc["groups"]["SIM-A1"]["fits"].values()))
    fit["soft_iron"] = fit["soft_iron"][:16]
    doc["sha256"] = ps._groups_sha256(doc["groups"])
    path.write_text(json.dumps(doc))


@pytest.mark.parametrize("damage", [
    pytest.param(_flip_a_fit_bit, id="flipped-bit"),
    pytest.param(_short_array_with_its_sha, id="short-array"),
    pytest.param(lambda p: p.write_bytes(p.read_bytes()[:-40]), id="truncated"),
    pytest.param(lambda p: p.write_bytes(b"\xff\x00garbage"), id="not-json"),
    pytest.param(lambda p: p.write_text("[]"), id="not-an-object"),
    pytest.param(lambda p: p.write_text(p.read_text().replace('"version": 1',
                                                              '"version": 99')),
                 id="other-version"),
])
def test_a_damaged_cache_is_ignored_with_a_warning_and_written_anew(tmp_path, ok_fits,
                                                                    mag_reads, damage):
    store = tmp_path / "s"
    ingest(_inputs(tmp_path / "in"), store)
    process_store(store)
    before = _processed(store)
    path = store / "processed" / SESSION_CACHE
    damage(path)
    assert verify_session_cache(store).startswith(f"{path}: ")
    res = CliRunner().invoke(main, ["store", "verify", str(store)])
    assert res.exit_code == 1 and f"FAILED  {path}: " in res.output
    for p in (store / "processed").iterdir():  # processed again: from the refitted sessions
        if p.name != SESSION_CACHE:
            shutil.rmtree(p) if p.is_dir() else p.unlink()
    mag_reads.clear()
    res = CliRunner().invoke(main, ["process", "--store", str(store)])
    assert res.exit_code == 0, res.output
    assert f"warning: {path}: " in res.output and "the sessions are fitted again" in res.output
    assert len(mag_reads) == 3 and "processed 3" in res.output
    assert _processed(store) == before  # results and the rewritten cache as first written
    assert verify_session_cache(store) is None
    assert CliRunner().invoke(main, ["store", "verify", str(store)]).exit_code == 0
    mag_reads.clear()
    report = process_store(store)
    assert len(report.unchanged) == 3 and not report.warnings and mag_reads == []


def test_a_raw_part_lost_after_caching_still_fails_its_walk(tmp_path, ok_fits):
    """The cache vouches for a walk's magnetometer columns only while its sensors part is
    there with its recorded sha256: a missing one fails the walk as without the cache."""
    store = tmp_path / "s"
    ingest(_inputs(tmp_path / "in"), store)
    process_store(store)
    part = next(store.glob(f"sensors/**/{B2.name[:24]}-*.parquet"))
    part.unlink()
    report = process_store(store)
    tid = B2.name[:24]
    assert list(report.failed) == [tid] and f"{part}: missing" in report.failed[tid]
    assert len(report.unchanged) == 2


CRASH = """
import sys
import survey.process_store as ps
from tests.test_session_fit_cache import ok_fit
ps.fit_ellipsoid = ok_fit
ps.process_store(sys.argv[1])
"""


@pytest.mark.parametrize("point", ["process:session-cache-before-rename",
                                   "process:session-cache-after-rename"])
def test_a_run_killed_while_writing_the_cache_leaves_the_old_or_the_new(tmp_path, ok_fits,
                                                                        mag_reads, point):
    inputs = _inputs(tmp_path / "in")
    ingest(inputs, tmp_path / "a")
    process_store(tmp_path / "a")
    path = tmp_path / "a" / "processed" / SESSION_CACHE
    old = path.read_bytes()
    later = _changed_mate(tmp_path / "later")
    ingest([later], tmp_path / "a")
    env = {**os.environ, "INDOORMAP_CRASH_AT": point}
    proc = subprocess.run([sys.executable, "-c", CRASH, str(tmp_path / "a")], env=env,
                          capture_output=True)
    assert proc.returncode == 70, proc.stderr.decode()
    assert verify_session_cache(tmp_path / "a") is None
    litter = list(path.parent.glob(".tmp-*"))
    if point.endswith("before-rename"):
        assert path.read_bytes() == old and len(litter) == 1  # the temporary of the new one
    else:
        assert path.read_bytes() != old and not litter
    mag_reads.clear()
    report = process_store(tmp_path / "a")
    assert not report.warnings and not list(path.parent.glob(".tmp-*"))
    assert len(mag_reads) == (2 if point.endswith("before-rename") else 0)
    ingest([inputs[0], later, B2], tmp_path / "b")
    process_store(tmp_path / "b")
    assert _processed(tmp_path / "a") == _processed(tmp_path / "b")


def test_a_fit_is_cached_bit_for_bit():
    """Every field of MagCalResult, NaN (with its sign bit), -0.0 and infinity included."""
    neg_nan = np.frombuffer(bytes.fromhex("000000000000f8ff"), "<f8")[0]
    fit = MagCalResult(status="ill-conditioned", method="ellipsoid",
                       hard_iron_ut=np.array([neg_nan, -0.0, 1 / 3]),
                       soft_iron=np.arange(9.0).reshape(3, 3) / 7, field_strength_ut=np.inf,
                       residual_rms_ut=float("nan"), condition_number=1e300, coverage=5e-324,
                       reason="r\u00e9ason", n_samples=20000,
                       hard_iron_se_ut=np.array([np.inf, -np.inf, 0.1]),
                       earth_field_ut=np.full(3, np.nan))
    doc = json.loads(json.dumps(ps._encode_fit(fit)))
    back = ps._decode_fit(doc)
    for f in dataclasses.fields(MagCalResult):
        a, b = getattr(fit, f.name), getattr(back, f.name)
        if isinstance(a, str | int) and not isinstance(a, float):
            assert a == b and type(a) is type(b)
        else:
            assert np.asarray(a, "<f8").tobytes() == np.asarray(b, "<f8").tobytes(), f.name
            assert np.shape(a) == np.shape(b) and type(a) is type(b)


def test_a_changed_fit_function_is_fitted_again_not_taken_from_the_cache(tmp_path, monkeypatch,
                                                                         mag_reads):
    """Before the cache every run fitted the sessions, so a change to fit_ellipsoid (or to
    reported_bias, calibration_sessions, session_fits) reached the walks at once (their
    inputs_sha256 holds the fit). With the cache the old fits were used until
    SESSION_FIT_VERSION was bumped by hand; the key now holds the fitting code's sha256."""
    store = tmp_path / "s"
    ingest(_inputs(tmp_path / "in"), store)
    process_store(store)  # the real fit: ill-conditioned on these flat-held walks
    real_fit = ps.fit_ellipsoid

    import functools

    @functools.wraps(real_fit)  # "a fix" of its body: the same signature and defaults
    def fixed_fit(raw, **kwargs):
        return dataclasses.replace(real_fit(raw, **kwargs), status="ok", reason="",
                                   hard_iron_ut=raw.mean(axis=0), soft_iron=np.eye(3))

    monkeypatch.setattr(ps, "fit_ellipsoid", fixed_fit)
    mag_reads.clear()
    report = process_store(store)
    assert mag_reads and "needs_fit" in report.processed
