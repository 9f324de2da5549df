"""``indoormap process`` and ``indoormap survey-report``: positioned, calibrated walks and QA."""

from __future__ import annotations

from pathlib import Path

import click

from localize.names import floor_key

from .process_store import process_store, processed_catalog, processed_table
from .progress import progress
from .publish import atomic_write_bytes, refuse_to_replace
from .store import SurveyStore


def _require_walks(selected, everything, site: str | None, floor: str | None) -> None:
    """An empty selection by ``--site``/``--floor`` is a usage error naming what there is."""
    if len(selected) or (site is None and floor is None):
        return
    have = sorted({f"{s}/{f}" for s, f in everything[["site", "floor"]].itertuples(index=False)})
    raise click.BadParameter(
        f"no walks for{f' site {site}' if site else ''}{f' floor {floor}' if floor else ''}"
        f"; the store has {', '.join(have) if have else 'no walks'} (site/floor)",
        param_hint="--site/--floor")


def _plan_floors(path: str, floors: list[str]) -> list[str]:
    """The floors a ``--floor-plan`` is read for: each floor of a plan of several floors
    that the walks are on, else the one its name or its one floor tag gives; a warning for
    a plan of no walks' floor (``floors``: the walks' floor keys)."""
    from mapping.floorplan import plan_floor_name, plan_levels

    levels = plan_levels(path)
    candidates = levels if len(levels) > 1 else [plan_floor_name(path), *levels]
    named = list({floor_key(n): n for n in candidates if floor_key(n) in floors}.values())
    if not named:
        of = (f"any of its floors ({', '.join(levels)})" if len(levels) > 1
              else " or ".join(f"floor {n!r}" for n in dict.fromkeys(candidates)))
        click.echo(f"warning: {path}: no walks of {of} to check against this plan (floors: "
                   f"{', '.join(floors)})", err=True)
    return named


@click.command("process")
@click.option("--store", "store_dir", required=True, type=click.Path(file_okay=False,
                                                                     exists=True))
@click.option("--site", default=None, help="Only this site (id or partition name).")
@click.option("--floor", default=None, help="Only this floor (name or id).")
@click.option("--floor-plan", "floor_plans", multiple=True, type=click.Path(exists=True),
              help="A floor plan whose reachable area flags legs leaving it: a floor folder "
                   "(geojson_map.json [+ floor_info.json]; the folder's name is the floor) or "
                   "a plan file (GeoJSON, DXF; the file's name without suffix is the floor, or a "
                   "GeoJSON's features tagged 'level' give its floors). "
                   "Repeatable; two plans of one floor are refused.")
def process_command(store_dir: str, site: str | None, floor: str | None,
                    floor_plans: tuple[str, ...]) -> None:
    """Position every sample, scan and beacon row along its walk, calibrate the magnetometer,
    rotate the field into the map frame, and store the results (new or changed walks only)."""
    from mapping.floorplan import plan_file, read_floor_plan

    store = SurveyStore.open(store_dir)
    reachable = {}
    cat = store.traces(site, floor)
    everything = store.traces(None, None)
    if not len(everything):
        raise click.ClickException(f"{store.root}: the store holds no walks; ingest traces "
                                   f"into it first (indoormap ingest PATH --store "
                                   f"{store_dir})")
    _require_walks(cat, everything, site, floor)
    plan_of: dict[tuple[str, str], str] = {}  # (site, floor) -> the plan given for it
    floors = sorted(cat["floor"].astype(str).unique())
    for fp in floor_plans:
        for name in _plan_floors(fp, floors):
            plan = read_floor_plan(fp, level=name)
            for repair in plan.repairs:
                click.echo(f"warning: {repair}", err=True)
            key = floor_key(name)
            sites = cat.loc[cat["floor"] == key, "site"].unique()
            if len(sites) > 1:
                folder = Path(fp).resolve()
                site_dir = (folder if folder.is_dir() else folder.parent).parent.name
                if site_dir in sites:  # an ILC-style site/floor folder names its site
                    sites = [site_dir]
                else:
                    click.echo(f"warning: {fp}: used for floor {name!r} of every site that "
                               f"has one ({', '.join(sorted(sites))}); give --site to pick one",
                               err=True)
            for s in sites:
                other = plan_of.setdefault((s, key), fp)
                if plan_file(other).resolve() != plan_file(fp).resolve():  # the last one won
                    raise click.BadParameter(f"{other} and {fp} are both plans of floor "
                                             f"{name!r} of site {s} (by their names); give one",
                                             param_hint="--floor-plan")
                reachable[(s, key)] = plan.reachable
    with progress("process", len(cat), unit="walks") as update:
        report = process_store(store, site=site, floor=floor, reachable=reachable,
                               progress=update)
    for warning in report.warnings:
        click.echo(f"warning: {warning}", err=True)
    click.echo(f"walks: processed {len(report.processed)}, unchanged {len(report.unchanged)}, "
               f"skipped {len(report.skipped)}"
               + (f", failed {len(report.failed)}" if report.failed else ""))
    for tid, reason in report.skipped.items():
        click.echo(f"  skipped {tid}: {reason}")
    for tid, reason in report.failed.items():
        click.echo(f"  failed {tid}: {reason}", err=True)
    done = processed_catalog(store)
    done = done[done["trace_id"].isin(cat["trace_id"]) & (done["status"] == "ok")]
    decision = done["summary"].map(lambda d: d.get("calibration", ""))
    if len(done):
        click.echo("calibration: " + ", ".join(f"{n} {what}" for what, n in
                                               decision.value_counts().sort_index().items()))
    # our pooled fit matters only to walks the phone's own calibration did not serve
    relied = set(done.loc[decision.isin(["own-session-fit", "not-calibrated"]), "session"])
    relied &= set(report.sessions)
    if relied:
        click.echo("calibration sessions needing our pooled fit:")
    for key, s in report.sessions.items():
        if key in relied:
            click.echo(f"  {key:<28} {s['status']:<16} {s['reason']}")
    if report.failed:
        raise click.ClickException(
            f"{len(report.failed)} walks could not be read from the store (their part files "
            "are missing or damaged); the others were processed. Ingest their files again "
            "to repair them, then run process again")


@click.command("survey-report")
@click.option("--store", "store_dir", required=True, type=click.Path(file_okay=False,
                                                                     exists=True))
@click.option("--site", default=None)
@click.option("--floor", default=None)
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False), default=None,
              help="Also write the table as CSV.")
@click.option("--overwrite", is_flag=True, help="Replace an existing --csv file.")
@click.option("--legs", "list_legs", is_flag=True,
              help="List the flagged legs, a row each, instead of the walks.")
def survey_report_command(store_dir: str, site: str | None, floor: str | None,
                          csv_path: str | None, overwrite: bool, list_legs: bool) -> None:
    """Per-walk QA, a row per walk: status; steps; length_m (positioned track, m); legs and
    flagged legs (between waypoints; reasons at the end); step_k (the walk's Weinberg step
    factor K, step length = K (a_max - a_min)^(1/4), m / (m/s2)^(1/4)); calibration (the
    magnetometer calibration used); heading_offset_deg (median compass minus walking
    direction, deg); ufh_share (share of steps with the phone held flat and forward); session
    (calibration session). Why each skipped walk was skipped follows the table (and is the
    CSV's reason column).

    With --legs, a row per flagged leg: trace_id, leg (0 = from the first waypoint to the
    second, as validate counts them), its start time (t_start_ms, Unix ms) and duration_s,
    distance_m between its waypoints, speed_mps, step_m (mean step length), scale (step
    track over waypoint distance), heading_rotation_deg, waypoint_residual_m (how far the
    step track misses the leg's end waypoint) and flags."""
    if csv_path:
        from localize.cli_common import refuse_output_inside_data

        refuse_output_inside_data(Path(csv_path), "--csv")  # a file there damaged a bundle
        refuse_to_replace(csv_path, overwrite, suffixes=(".csv",))
    store = SurveyStore.open(store_dir)
    store.catalog()  # a damaged store is said, as by every command
    everything = cat = processed_catalog(store)
    if site is not None:
        cat = cat[cat["site"] == site]
    if floor is not None:
        cat = cat[cat["floor"] == floor]
    _require_walks(cat, everything, site, floor)
    if list_legs:
        _report_legs(store, site, floor, csv_path, overwrite)
        return
    rows = []
    for r in cat.itertuples(index=False):
        s = r.summary
        rows.append({
            "trace_id": r.trace_id, "floor": r.floor, "status": r.status,
            "steps": s.get("n_steps", ""), "length_m": round(s.get("walk_length_m", 0), 1),
            "legs": s.get("n_legs", ""), "flagged": s.get("n_flagged_legs", ""),
            "step_k": round(s.get("step_model", {}).get("k", float("nan")), 3),
            "calibration": s.get("calibration", ""),
            "heading_offset_deg": round(s.get("heading_offset_median_deg", float("nan")), 1),
            "ufh_share": round(s.get("attitude_share", {}).get("UFH", 0.0), 2),
            "session": r.session, "reason": r.reason if r.status == "skipped" else ""})
    import pandas as pd

    table = pd.DataFrame(rows)
    if csv_path:
        atomic_write_bytes(Path(csv_path), table.to_csv(index=False).encode(),
                           overwrite=overwrite)
    with pd.option_context("display.max_rows", None, "display.width", 200,
                           "display.max_colwidth", 40):
        click.echo(table.drop(columns="reason").to_string(index=False))
    for r in table[table["status"] == "skipped"].itertuples():  # a sentence each, not a cell
        click.echo(f"skipped {r.trace_id}: {r.reason}")
    try:
        legs = processed_table(store, "legs", site=site, floor=floor)
        flags = legs["flags"][legs["flags"] != ""].str.split(",").explode().value_counts()
        click.echo("flagged legs by reason: " + (", ".join(f"{k} {v}" for k, v in flags.items())
                                                 or "none"))
    except Exception as err:  # noqa: BLE001 - the report stays useful without the legs table
        click.echo(f"(no leg table: {err})")


#: what ``survey-report --legs`` shows of the legs table, with its rounding
_LEG_COLUMNS = {"trace_id": None, "leg": None, "t_start_ms": 0, "duration_s": 1,
                "distance_m": 1, "speed_mps": 2, "step_m": 2, "scale": 2,
                "heading_rotation_deg": 1, "waypoint_residual_m": 2, "flags": None}


def _report_legs(store: SurveyStore, site: str | None, floor: str | None,
                 csv_path: str | None, overwrite: bool) -> None:
    """``survey-report --legs``: the flagged legs of the walks chosen, a row each."""
    import pandas as pd

    legs = processed_table(store, "legs", site=site, floor=floor)
    flagged = legs[legs["flags"] != ""]
    table = pd.DataFrame({c: flagged[c] if r is None else flagged[c].round(r)
                          for c, r in _LEG_COLUMNS.items()})
    table["t_start_ms"] = table["t_start_ms"].astype("int64")
    if csv_path:
        atomic_write_bytes(Path(csv_path), table.to_csv(index=False).encode(),
                           overwrite=overwrite)
    if not len(table):
        click.echo(f"no flagged legs among {legs['trace_id'].nunique()} walk(s)")
        return
    with pd.option_context("display.max_rows", None, "display.width", 250):
        click.echo(table.to_string(index=False))
    click.echo(f"{len(table)} flagged leg(s) of {table['trace_id'].nunique()} walk(s), "
               f"{len(legs)} legs in all")
