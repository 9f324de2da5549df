"""``indoormap ingest``: trace files and walk plans into a survey store."""

from __future__ import annotations

import sys

import click

from .errors import at_path
from .ingest import IngestSummary, ingest
from .progress import progress


@click.command("ingest")
@click.argument("paths", nargs=-1, required=True, type=click.Path(exists=True))
@click.option("--store", "store_dir", required=True, type=click.Path(file_okay=False),
              help="Survey store folder (created if missing).")
@click.option("--strict", is_flag=True,
              help="Fail on the first malformed line instead of skipping and counting it.")
@click.option("--workers", type=click.IntRange(1, 64), default=1, show_default=True,
              help="Worker processes for parsing (each also uses pyarrow's threads; more than "
                   "one pays off on large inputs only).")
def ingest_command(paths: tuple[str, ...], store_dir: str, strict: bool, workers: int) -> None:
    """Ingest survey traces (.txt, .txt.gz; folders are searched) and walk plans (.geojson)
    into the Parquet survey store STORE. Files already stored (same sha256) are skipped; a
    changed file replaces its old rows."""
    with progress("ingest", unit="files") as update:
        summary = ingest(paths, store_dir, strict=strict, workers=workers, progress=update)
    click.echo(format_summary(summary))
    if summary.failed:
        sys.exit(1)


def format_summary(s: IngestSummary) -> str:
    """The summary table printed after an ingest."""
    lines = ["files:    " + ", ".join(f"{k} {v}" for k, v in sorted(s.status_counts().items()))]
    r = s.rows
    lines.append(f"ingested: {r['traces']} traces, {r['lines']} lines, {r['sensor_rows']} sensor "
                 f"rows, {r['scans']} Wi-Fi scans ({r['wifi_rows']} rows), {r['ble_rows']} "
                 f"beacon rows, {r['waypoints']} waypoints")
    for title, counts in (("skipped (undocumented types)", s.skipped),
                          ("bad lines (by reason)", s.bad),
                          ("rows dropped or mended (by rule)", s.dropped)):
        total = sum(counts.values())
        lines.append(f"{title}: {total}")
        lines.extend(f"  {k:<44} {v:>10}" for k, v in sorted(counts.items()))
    for o in s.failed:
        lines.append(f"FAILED {at_path(o.path, str(o.detail))}")
    replaced = [o for o in s.outcomes if o.status == "changed" and o.detail]
    for o in replaced[:20]:  # a stored walk replaced by another file of its name
        lines.append(f"changed {o.trace_id}: now {o.path}; {o.detail}")
    if len(replaced) > 20:
        lines.append(f"changed: {len(replaced) - 20} more")
    if s.messages:
        lines.append("first problems:")
        lines.extend(f"  {m}" for m in s.messages[:10])
    return "\n".join(lines)
