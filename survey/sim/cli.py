"""``indoormap simulate``: write a synthetic surveyed site (traces, maps, ground truth)."""

from __future__ import annotations

import time
from pathlib import Path

import click

from ..trace_format import STREAM_NAMES


#: What the simulator writes in a floor folder (besides the traces it lists);
#: ``walk_plan.geojson`` is the routes file's name in sites simulated before it was renamed.
FLOOR_FILES = ("floor_info.json", "geojson_map.json", "planned_routes.geojson",
               "walk_plan.geojson", "path_data_files")


def not_simulated(site_dir: Path) -> list[Path]:
    """Entries of a simulated site folder that its last simulation did not write (by its
    ``truth/site.json``): anything beside ``truth/`` and its floors, or in a floor folder
    beside :data:`FLOOR_FILES` and the walks' traces (``truth/`` is the simulator's whole).

    Raises
    ------
    PublishError
        ``truth/site.json`` cannot be read as a simulated site's."""
    import json

    from ..errors import PublishError

    path = site_dir / "truth" / "site.json"
    try:
        truth = json.loads(path.read_text())
        floors = {str(f["name"]) for f in truth["floors"]}
        traces = {str(w["trace_path"]) for w in truth["walks"]}
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise PublishError(f"{path}: not a simulated site's truth ({err}); --overwrite "
                           "replaces simulated sites only, move the folder away first") from err
    foreign = []
    for entry in sorted(site_dir.iterdir()):
        if entry.name == "truth" and entry.is_dir() and not entry.is_symlink():
            continue
        if entry.name not in floors or not entry.is_dir() or entry.is_symlink():
            foreign.append(entry)
            continue
        for f in sorted(entry.iterdir()):
            if f.name not in FLOOR_FILES:
                foreign.append(f)
        walks = entry / "path_data_files"
        if walks.is_dir():
            foreign += [t for t in sorted(walks.iterdir())
                        if str(t.relative_to(site_dir)) not in traces]
    return foreign


@click.command("simulate")
@click.argument("out_dir", type=click.Path(file_okay=False, dir_okay=True, path_type=Path))
@click.option("--preset", type=click.Choice(["sample", "default"]), default="sample",
              show_default=True, help="Site size and survey effort.")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Seed of the whole simulation [default: the preset's, 7].")
@click.option("--overwrite", is_flag=True, help="Replace OUT_DIR if it exists.")
def simulate(out_dir: Path, preset: str, seed: int | None, overwrite: bool) -> None:
    """Simulate a surveyed site into OUT_DIR (published atomically).

    Writes per floor floor_info.json, geojson_map.json, planned_routes.geojson and
    path_data_files/*.txt.gz, and the ground truth under OUT_DIR/truth/. The same preset and
    seed always give byte-identical files.
    """
    from .site import SiteParams, simulate_site

    t0 = time.perf_counter()
    from ..errors import PublishError
    from ..publish import refuse_to_replace

    # indoormap's errors (PublishError, SimulationError) propagate to the main group, which
    # prints them on one line and exits with code 1
    refuse_to_replace(out_dir, overwrite)
    if out_dir.exists() and any(out_dir.iterdir()):
        if not (out_dir / "truth" / "site.json").is_file():
            raise PublishError(f"{out_dir} exists and is not a simulated site; --overwrite "
                               "replaces simulated sites only, move it away first")
        foreign = not_simulated(out_dir)
        if foreign:  # e.g. a build's bundles or store kept in the site folder
            raise PublishError(
                f"{out_dir} holds files the simulator did not write ("
                + ", ".join(str(p.relative_to(out_dir)) for p in foreign[:5])
                + (" ..." if len(foreign) > 5 else "") + "); --overwrite would delete them: "
                "move them out of the site folder first")
    params = SiteParams.preset_params(preset, seed=seed)
    site = simulate_site(params, out_dir, overwrite=overwrite)
    elapsed = time.perf_counter() - t0
    walks = site.walks
    devices = sorted({w.device_id for w in walks})
    sessions = sorted({w.session_id for w in walks})
    samples = sum(w.n_samples for w in walks)
    click.echo(f"simulated site {site.site_id} (preset {params.preset}, seed {params.seed}) "
               f"-> {site.out_dir}")
    click.echo(f"  floors {', '.join(site.floors)}; {len(walks)} walks, "
               f"{len(devices)} devices, {len(sessions)} calibration sessions")
    for floor in site.floors:
        fw = [w for w in walks if w.floor == floor]
        click.echo(f"  {floor}: {len(fw)} walks, {sum(w.length_m for w in fw):.0f} m, "
                   f"{sum((w.end_ms - w.start_ms) for w in fw) / 1000:.0f} s")
    click.echo(f"  {samples * len(STREAM_NAMES)} sensor rows ({samples} sample times x "
               f"{len(STREAM_NAMES)} streams), {sum(w.n_wifi_rows for w in walks)} Wi-Fi rows, "
               f"{sum(w.n_ble_rows for w in walks)} beacon rows")
    click.echo(f"  {site.n_files} files, {site.n_bytes / 1e6:.2f} MB in {elapsed:.1f} s")
