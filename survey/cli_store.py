"""``indoormap store info|verify``: what a survey store holds, and whether it is whole."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from .process_store import processed_catalog, verify_processed, verify_session_cache
from .progress import progress
from .store import SurveyStore


@click.group("store")
def store_group() -> None:
    """Inspect and verify survey stores (what `ingest` writes and `process` adds to)."""


@store_group.command("info")
@click.argument("store_dir", type=click.Path(file_okay=False, exists=True, path_type=Path))
def store_info(store_dir: Path) -> None:
    """Traces and rows per site and floor, and how many walks are processed, by status."""
    store = SurveyStore.open(store_dir)
    cat = store.catalog()
    click.echo(f"{store_dir}: survey store, schema version {store.schema_version()}, "
               f"{len(cat)} traces")
    if len(cat):
        table = cat.groupby(["site", "floor"]).agg(
            traces=("trace_id", "size"), sensor_rows=("n_sensor_rows", "sum"),
            scans=("n_scans", "sum"), ble_rows=("n_ble_rows", "sum"),
            waypoints=("n_waypoints", "sum"), bad_lines=("n_bad_lines", "sum"))
        click.echo(table.reset_index().to_string(index=False))
    if (store.root / "processed" / "catalog.parquet").exists():
        counts = processed_catalog(store)["status"].value_counts().sort_index()
        click.echo("processed: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    else:
        click.echo("processed: not yet (run `indoormap process`)")


@store_group.command("verify")
@click.argument("store_dir", type=click.Path(file_okay=False, exists=True, path_type=Path))
def store_verify(store_dir: Path) -> None:
    """Read every stored and processed file with all the checks a read makes (sha256, size,
    rows, columns, trace id, page checksums), and the session-fit cache (its sha256 and
    format). Exit 1 if any fails; ingesting a failed trace's file again repairs it, and
    `process` then redoes its walk (and refits a damaged cache)."""
    store = SurveyStore.open(store_dir)
    catalog = store.catalog()
    n = len(catalog)
    with progress("verify", n, unit="traces") as update:
        raw = store.verify(progress=update)
    processed = verify_processed(store)
    cache = verify_session_cache(store)
    for what, problems in (("trace", raw), ("processed walk", processed)):
        for tid, problem in problems.items():
            click.echo(f"FAILED  {what} {tid}: {problem}")
    if cache:
        click.echo(f"FAILED  {cache} (the next `indoormap process` fits "
                   "the sessions again and rewrites it)")
    stray = store.stray_files(catalog)
    if stray:  # not a failure: never read
        click.echo(f"note    {len(stray)} file(s) the catalog does not name, e.g. {stray[0]} "
                   "(an ingest running now, or one interrupted: the next `indoormap ingest` "
                   "deletes them)")
    if raw or processed or cache:
        sys.exit(1)
    click.echo(f"ok      {store_dir} ({n} traces)")
