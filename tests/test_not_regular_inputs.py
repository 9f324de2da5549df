"""Small files read whole (floor plans, walk plans, --exclude lists) are read only if they are
regular files, and only up to a size: a FIFO named ``*.geojson`` in a trace folder hung
``ingest`` and ``build`` (every ``*.geojson`` is checked for being a walk plan), and a link to
``/dev/zero`` as a floor plan or ``--exclude @FILE`` ran out of memory. And ``--csv FILE
--overwrite`` replaces a CSV file only: it wrote over a store's catalog.parquet."""

from __future__ import annotations

import os
import shutil
import signal
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from mapping.cli_build import exclude_names
from mapping.floorplan import FloorPlanError, read_floor_plan
from survey.cli import main
from survey.errors import SurveyFormatError
from survey.ingest import ingest
from survey.store import SurveyStore
from survey.walkline import is_walk_plan, read_walk_plan

from radio_fixtures import SITE, sample_store  # noqa: F401  (fixture)

needs_fifo = pytest.mark.skipif(not hasattr(os, "mkfifo") or not Path("/dev/zero").exists(),
                                reason="FIFOs and /dev/zero are POSIX")


@pytest.fixture
def no_hang():
    """Fail (SIGALRM) instead of blocking forever on a FIFO."""
    def alarm(*_):
        raise TimeoutError("blocked on a FIFO")
    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(20)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


@needs_fifo
def test_a_fifo_or_dev_zero_named_geojson_is_no_walk_plan_and_ingest_goes_on(tmp_path, no_hang):
    folder = tmp_path / "walks"
    folder.mkdir()
    os.mkfifo(folder / "plan.geojson")
    (folder / "zero.geojson").symlink_to("/dev/zero")
    trace = min((SITE / "F1" / "path_data_files").glob("*.txt.gz"))
    shutil.copy(trace, folder / trace.name)
    assert not is_walk_plan(folder / "plan.geojson") and not is_walk_plan(folder / "zero.geojson")
    for name in ("plan.geojson", "zero.geojson"):
        with pytest.raises(SurveyFormatError, match="not a regular file"):
            read_walk_plan(folder / name)
    ingest([folder], tmp_path / "store")
    assert len(SurveyStore.open(tmp_path / "store").catalog()) == 1


@needs_fifo
@pytest.mark.parametrize("kind", ["fifo", "dev_zero"])
def test_a_floor_plan_or_exclude_list_that_is_no_regular_file_is_refused(tmp_path, no_hang,
                                                                        kind):
    floor = tmp_path / "F1"
    shutil.copytree(SITE / "F1", floor, ignore=shutil.ignore_patterns("path_data_files"))
    plan = floor / "geojson_map.json"
    plan.unlink()
    if kind == "fifo":
        os.mkfifo(plan)
    else:
        plan.symlink_to("/dev/zero")
    with pytest.raises(FloorPlanError, match=r"geojson_map.json: cannot read .*not a regular"):
        read_floor_plan(floor)
    with pytest.raises(click.BadParameter, match="not a regular file"):
        exclude_names((f"@{plan}",))


def test_csv_overwrite_replaces_a_csv_only(sample_store, tmp_path):  # noqa: F811
    store = tmp_path / "store"
    shutil.copytree(sample_store, store)
    catalog = store / "catalog.parquet"
    before = catalog.read_bytes()
    res = CliRunner().invoke(main, ["survey-report", "--store", str(store), "--csv",
                                    str(catalog), "--overwrite"])
    assert res.exit_code == 2 and "is inside the survey store" in res.output  # session 39
    assert catalog.read_bytes() == before
    plan = tmp_path / "plan.geojson"  # another input, outside the store
    plan.write_text("{}")
    res = CliRunner().invoke(main, ["survey-report", "--store", str(store), "--csv",
                                    str(plan), "--overwrite"])
    assert res.exit_code == 1 and "is not a .csv file; --overwrite replaces only" in res.output
    assert plan.read_text() == "{}"
    table = tmp_path / "walks.csv"
    table.write_text("old")
    res = CliRunner().invoke(main, ["survey-report", "--store", str(store), "--csv",
                                    str(table), "--overwrite"])
    assert res.exit_code == 0, res.output
    assert table.read_text().startswith("trace_id,floor,status")


@needs_fifo
def test_a_fifo_in_place_of_a_stores_or_publications_own_files_is_refused(sample_store,
                                                                         tmp_path, no_hang):
    """store.json, the session-fit cache and a build folder's publication journal are read as
    capped regular files (session 39: a FIFO in their place made `store info`, `process` and
    every reader of a build folder wait forever)."""
    from survey.errors import PublishError, StoreError
    from survey.process_store import SESSION_CACHE, store_session_fits
    from survey.publish import JOURNAL_NAME, finish_interrupted_publication

    store = tmp_path / "store"
    shutil.copytree(sample_store, store)
    cache = store / "processed" / SESSION_CACHE
    cache.unlink()
    os.mkfifo(cache)
    fits = store_session_fits(SurveyStore.open(store), ["SIM-A1"])
    assert "damaged session-fit cache (NotRegularFile" in fits.warnings[0], fits.warnings
    (store / "store.json").unlink()
    os.mkfifo(store / "store.json")
    with pytest.raises(StoreError, match="store.json: unreadable .*not a regular file"):
        SurveyStore.open(store)
    os.mkfifo(tmp_path / JOURNAL_NAME)
    with pytest.raises(PublishError, match="unreadable publication journal.*not a regular"):
        finish_interrupted_publication(tmp_path)
