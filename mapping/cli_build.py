"""``indoormap build``: survey traces or a store and floor plans to map bundles."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

import click
import numpy as np
import pandas as pd

from survey.errors import PublishError, RegistryError, RollbackRefused, at_path
from survey.publish import (
    JOURNAL_NAME,
    refuse_to_replace,
    remove_stale_temporaries,
    replace_together,
    tmp_prefix,
)
from survey.process_store import walks_per_site
from survey.regular_files import read_regular
from localize.names import floor_key
from survey.trace_format import bad_lines_summary

from .build import ON_PLAN_M, BuildError, BuildParams, build_floor
from .bundle_writer import write_bundle
from .cli_bundle import already_published_text
from .floorplan import FloorPlan, plan_floor_name, read_floor_plan
from .floorplan_dxf import DXF_ROLES
from .grid import reachable_mask
from .radio_build import build_site_radio, format_share, n_floors_text
from .registry import SITE_BUNDLE, Registry, safe_name

if TYPE_CHECKING:  # an annotation: ingest is imported when a build runs
    from survey.ingest import IngestSummary


#: Below this share of the reachable area within 2 m of a sample a build warns: less than half
#: the floor mapped (validate's own coverage check asks for 80 %).
THIN_COVERAGE = 0.5
#: Below this share of the samples on the plan (:func:`mapping.build.samples_on_plan`) a build
#: warns; below :data:`mapping.build.MIN_SAMPLES_ON_PLAN` it refuses the floor.
SAMPLES_OFF_PLAN_WARNING = 0.9


def _iso_time(ctx: click.Context, param: click.Parameter, text: str | None) -> str | None:
    """``--build-time`` checked (a click callback): an ISO 8601 date and time, kept as given."""
    if text is None:
        return None
    try:
        datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError as err:
        raise click.BadParameter(f"{text!r} is not an ISO 8601 time such as "
                                 "2026-11-22T10:00:00Z", param_hint="--build-time") from err
    return text


def _finite(ctx: click.Context, param: click.Parameter, value: float) -> float:
    """A float option checked for NaN (click's ranges let it through)."""
    if not np.isfinite(value):
        raise click.BadParameter(f"{value} is not a number", param=param)
    return value


def dxf_layer_roles(given: tuple[str, ...], plan_file: Path | None) -> dict[str, tuple[str, ...]]:
    """``--dxf-layer ROLE=LAYER`` options as role -> layer names; a usage error for a bad
    one, or for any without a DXF ``--plan``."""
    if not given:
        return {}
    if plan_file is None or plan_file.suffix.lower() != ".dxf":
        raise click.UsageError("--dxf-layer names the layers of a DXF --plan")
    roles: dict[str, list[str]] = {}
    for item in given:
        role, sep, layer = item.partition("=")
        if not sep or role.strip() not in DXF_ROLES or not layer.strip():
            raise click.BadParameter(f"{item!r} is not ROLE=LAYER with ROLE one of "
                                     f"{', '.join(DXF_ROLES)}", param_hint="--dxf-layer")
        roles.setdefault(role.strip(), []).append(layer.strip())
    return {role: tuple(names) for role, names in roles.items()}


def check_grids(plans: dict[Path, FloorPlan], params: BuildParams) -> None:
    """Every floor's grid (plans by the path they were read from) at ``--cell`` within
    :data:`mapping.grid.MAX_GRID_CELLS` and with some reachable cell; else a usage error
    naming the plan and ``--cell``, before the ingest (the finer cells of narrow kernels are
    skipped where they would exceed the cap)."""
    for path, plan in plans.items():
        try:
            grid = plan.grid(params.cell_m)
        except ValueError as err:
            raise click.UsageError(f"{path}: {err}; check the plan's units (a floor "
                                   "drawn in mm without units reads 1000 times too large), "
                                   "or raise --cell") from err
        if not reachable_mask(grid, plan.reachable).any():
            raise click.UsageError(
                f"{path}: no cell centre of a {params.cell_m:g} m grid lies in the plan's "
                f"reachable area ({plan.reachable.area:.1f} m^2); lower --cell")


def _is_floor_dir(p: Path) -> bool:
    return (p / "geojson_map.json").exists()


def _floor_dirs_in(path: Path) -> list[Path]:
    """The floor folders directly in ``path``, sorted."""
    return sorted(p for p in path.iterdir() if p.is_dir() and _is_floor_dir(p))


def _has_floor_dirs(path: Path) -> bool:
    """Whether ``path`` is a folder with floor folders in it (False when it cannot be
    listed: a hint's test, never an error)."""
    try:
        return path.is_dir() and bool(_floor_dirs_in(path))
    except OSError:
        return False


def floors_of(path: Path) -> list[Path]:
    """A floor folder itself, or the floor folders of a site folder."""
    floors = [path] if _is_floor_dir(path) else _floor_dirs_in(path)
    if not floors:
        hint = "a folder of traces needs its floor plan: --plan PLAN"
        sites = [p for p in sorted(path.iterdir()) if _has_floor_dirs(p)]
        if (path.parent / "geojson_map.json").exists():  # <floor>/path_data_files
            hint = f"its floor folder is {path.parent}"
        elif len(sites) == 1:  # the folder above a site
            hint = f"it holds the site folder {sites[0].name}: build {sites[0]}"
        elif sites:
            hint = (f"it holds the site folders {', '.join(p.name for p in sites)}: build "
                    f"each, e.g. {sites[0]}")
        raise click.UsageError(f"{path}: neither a floor folder (with geojson_map.json) nor a "
                               f"site folder of floors; {hint}")
    if floors != [path]:  # a site: a floor folder without its plan was passed over
        planless = [p.name for p in sorted(path.iterdir()) if p.is_dir() and p not in floors
                    and any((p / n).exists() for n in ("path_data_files", "floor_info.json"))]
        if planless:
            raise click.UsageError(
                f"{path}: the floor folder{'s' if len(planless) > 1 else ''} "
                f"{', '.join(planless)} of this site {'have' if len(planless) > 1 else 'has'} "
                "no geojson_map.json: add the plan, or move the folder out of the site folder "
                "(the site's floor model would be made without its walks)")
    for floor in floors:  # before the work, not when publishing
        check_floor_bundle_name(floor.name, f"{floor}: the folder name")
    return floors


def walks_folder(floor: Path) -> Path:
    """Where a floor folder's walks are read from: its ``path_data_files/`` (the ILC
    layout), else the floor folder itself (walk plans and trace files anywhere in it; floor
    plans and planned routes are no walks)."""
    data = floor / "path_data_files"
    return data if data.is_dir() else floor


def check_floor_bundle_name(name: str, what: str) -> None:
    """A usage error unless ``name`` can name a floor's bundle folder (not the site bundle's
    ``_site``, nor a name no folder can have); ``what`` says where the name came from."""
    try:
        if safe_name(name) == SITE_BUNDLE:
            raise RegistryError(f"{SITE_BUNDLE!r} names the site bundle")
    except RegistryError as err:
        raise click.UsageError(f"{what} {name!r} cannot name a floor bundle folder ({err})"
                               ) from err


def ingested_from(catalog: pd.DataFrame, summary: IngestSummary, folder: Path
                  ) -> pd.DataFrame:
    """Catalog rows of the walks an ingest read (or found already stored) under ``folder``:
    trace files, and walk plans' walks by their plan (their logs may lie elsewhere,
    ``../logs/x.csv``).

    Paths are compared as found, not resolved: a folder of symbolic links to traces elsewhere
    (a subset of a survey, say) holds those traces."""
    root = Path(os.path.abspath(folder))
    ids = {o.trace_id for o in summary.outcomes
           if o.status != "failed"
           and Path(os.path.abspath(o.plan or o.path)).is_relative_to(root)}
    return catalog[catalog["trace_id"].isin(ids)]


def floor_of_traces(catalog: pd.DataFrame, summary: IngestSummary, source: Path) -> str:
    """The one floor of the traces an ingest read from ``source`` (a ``--plan`` build without
    ``--floor``); a usage error when they are of none or several."""
    names = sorted(ingested_from(catalog, summary, source)["floor"].astype(str).unique())
    if not names:
        raise click.UsageError(f"{source}: no readable walks to build a floor from")
    if len(names) > 1:
        raise click.UsageError(f"{source}: walks of floors {', '.join(names)}; name the "
                               "plan's floor with --floor")
    check_floor_bundle_name(names[0], f"{source}: the walks' floor")
    return names[0]


def check_plan_floor(plan: FloorPlan, plan_file: Path, catalog: pd.DataFrame,
                     summary: IngestSummary, source: Path) -> None:
    """A usage error when ``plan`` says it is of another floor than the walks of ``source``
    record (``build TRACES --plan`` given the wrong floor's plan: the bundle would have been
    built, with only its coverage to show it); ``--floor`` builds it anyway. Walks that
    record no floor (they take the plan's) are not checked; a walk's floor matches by name,
    id or store key (``Floor 2`` is stored as ``Floor_2``)."""
    if not plan.floor_name:
        return
    mine = ingested_from(catalog, summary, source)
    recorded = mine[(mine["floor_name"] != "") | (mine["floor_id"] != "")]
    if recorded.empty:
        return
    said = {plan.floor_name, floor_key(plan.floor_name)}
    if said & (set(recorded["floor_name"]) | set(recorded["floor_id"])
               | set(recorded["floor"].astype(str))):
        return
    walks = ", ".join(sorted(set(recorded["floor"].astype(str))))
    raise click.UsageError(f"{plan_file} says it is the plan of floor {plan.floor_name}, "
                           f"but the walks in {source} are recorded as floor {walks}; give "
                           f"floor {walks}'s plan, or --floor {walks} to build on this one")


def check_floor_names(catalog: pd.DataFrame, summary: IngestSummary, floor: str,
                      folder: Path, say: Callable[[str], None], *, planned: bool = False
                      ) -> None:
    """The traces read from ``folder`` for ``floor``: a usage error when none of them is of
    that floor (the folder is named otherwise than the traces' floor), a note of those left
    out because they are of another floor."""
    mine = ingested_from(catalog, summary, folder)
    other = mine[(mine["floor"] != floor) & (mine["floor_id"] != floor)]
    if len(mine) and len(other) == len(mine):
        names = ", ".join(sorted(other["floor"].astype(str).unique()))
        fix = ("give --floor that name" if planned else
               "name the floor folder after it, or build with --plan and --floor")
        raise click.UsageError(f"{folder}: its walks are recorded as floor {names}, not "
                               f"{floor}; {fix}")
    if len(other):
        say(f"  left out of {floor}: {len(other)} walk(s) in {folder} recorded as floor "
            f"{', '.join(sorted(other['floor'].astype(str).unique()))}")


#: Largest ``--exclude @FILE`` read (bytes): a list of trace names.
MAX_NAME_LIST_BYTES = 64 * 2**20


def exclude_names(exclude: tuple[str, ...]) -> list[str]:
    """The walk names ``--exclude`` gives: each value, or with ``@FILE`` the file's lines
    (blank lines and ``#`` comments left out)."""
    names = []
    for item in exclude:
        if item.startswith("@"):
            try:
                text = read_regular(item[1:], MAX_NAME_LIST_BYTES).decode("utf-8")
            except (OSError, UnicodeDecodeError) as err:
                raise click.BadParameter(f"cannot read {item[1:]} ({err})",
                                         param_hint="--exclude") from err
            names += [n.strip() for n in text.splitlines() if n.strip()
                      and not n.lstrip().startswith("#")]
        else:
            names.append(item)
    return names


def check_exclude_early(names: list[str], inputs: list[Path]) -> None:
    """Before any work: a usage error names an ``--exclude`` name (:func:`exclude_names`)
    that matches no walk under ``inputs`` (a trace file by its name, or its trace id: the
    name without ``.txt``/``.txt.gz``; a walk plan's walk by its ``walk_id`` or its sensor
    log's name, with or without ``.csv``), rather than after the whole ingest
    (:func:`excluded_walks` checks again on the ingested walks)."""
    from survey.ingest import find_inputs
    from survey.trace_reader import trace_id_from_path
    from survey.walkline import plan_walk_names

    if not names:
        return
    files, plans = find_inputs(p for p in inputs if p.exists())
    known = {f.name for f in files} | {trace_id_from_path(f) for f in files}
    for plan in plans:
        known |= plan_walk_names(plan)  # nothing for GeoJSON that is no walk plan
    unknown = [n for n in names if n not in known]
    if unknown:
        raise click.BadParameter(f"{unknown[0]!r} is no walk of this build (a trace id, a "
                                 "trace file's name or a walk plan's walk_id or sensor log "
                                 f"under {', '.join(map(str, inputs))})"
                                 + (f"; {len(unknown) - 1} more" if len(unknown) > 1 else ""),
                                 param_hint="--exclude")


def one_site(catalog: pd.DataFrame, inputs: list[Path]) -> str | None:
    """The one site (the store's ``site`` key) of the walks a build reads from ``inputs``
    (``catalog`` without the walks :func:`excluded_walks` leaves out, so only walks under
    ``inputs``; None when none is left); a BuildError naming the traces of the other sites
    when they are of several (a trace copied from another building would be merged into the
    maps, and the bundles would take whichever site sorted first)."""
    counts = catalog["site"].value_counts()
    if counts.empty:
        return None
    if len(counts) > 1:
        others = catalog[catalog["site"] != counts.index[0]]
        raise BuildError(
            f"{', '.join(map(str, inputs))}: walks of {len(counts)} sites ("
            f"{walks_per_site(catalog)}), e.g. " + ", ".join(others["source_path"].head(3))
            + "; move the other sites' traces out or --exclude them")
    return str(counts.index[0])


def excluded_walks(catalog: pd.DataFrame, summary: IngestSummary, inputs: list[Path],
                   names: list[str], say: Callable[[str], None], *, floors: list[str]
                   ) -> set[str]:
    """Trace ids a build leaves out: the walks of a ``--store`` that are not under its input
    folders (said), and those ``--exclude`` names (:func:`exclude_names`) by trace id or
    file name; a usage error names one that matches no walk, or a floor of ``floors`` (those
    built) whose every walk of the inputs it names (the build said so naming its temporary
    store)."""
    used = set().union(*(set(ingested_from(catalog, summary, f)["trace_id"]) for f in inputs))
    outside = set(catalog["trace_id"]) - used
    if outside:
        say(f"  left out: {len(outside)} walk(s) of the store not under "
            f"{', '.join(map(str, inputs))}")
    mine = catalog[catalog["trace_id"].isin(used)]
    file_names = mine["source_path"].astype(str).map(lambda p: Path(p).name)
    stems = file_names.str.replace(r"\.(txt(\.gz)?|csv)$", "", regex=True)
    dropped = set()
    for name in names:
        hit = mine["trace_id"].eq(name) | file_names.eq(name) | stems.eq(name)
        if not hit.any():
            raise click.BadParameter(f"{name!r} is no walk of this build (a trace id, a "
                                     "trace file's name or a walk plan's sensor log)",
                                     param_hint="--exclude")
        dropped |= set(mine.loc[hit, "trace_id"])
    for floor in floors:
        walks = mine.loc[mine["floor"] == floor, "trace_id"]
        if dropped and len(walks) and walks.isin(list(dropped)).all():
            raise click.BadParameter(f"it leaves floor {floor!r} no walk to build from (it "
                                     f"names all {len(walks)})", param_hint="--exclude")
    if dropped:
        say(f"  excluded: {len(dropped)} walk(s) (--exclude)")
    return outside | dropped


#: Prefix of a build's temporary survey store in the system's temporary folder.
TMP_STORE_PREFIX = "indoormap-build-"


@contextlib.contextmanager
def staging_folder(out: Path) -> Iterator[Path]:
    """A temporary folder inside ``out`` (created if missing) where a build writes its
    bundles before they are moved into place together; removed on the way out, and so is
    ``out`` when this created it and it stayed empty (a failed build leaves nothing). Kept
    while a publication journal is in ``out`` (replace_together could not undo its moves):
    whoever finishes the journal moves the staged bundles in, and the next build then
    removes the folder."""
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(out)
    stage = Path(tempfile.mkdtemp(prefix=tmp_prefix(), dir=out))
    try:
        yield stage
    finally:
        if not (out / JOURNAL_NAME).exists():
            shutil.rmtree(stage, ignore_errors=True)
        if created and not any(out.iterdir()):
            out.rmdir()


@click.command("build")
@click.argument("source", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("-o", "--out", "out", required=True, type=click.Path(path_type=Path),
              help="Output folder: one bundle folder per floor (OUT/<floor>).")
@click.option("--store", "store_dir", type=click.Path(path_type=Path), default=None,
              help="Survey store to ingest SOURCE into and keep (default: a temporary "
                   "store). Only SOURCE's walks are built; others in the store are left out.")
@click.option("--registry", "registry_dir", type=click.Path(path_type=Path), default=None,
              help="Also publish every bundle into this registry and make it current.")
@click.option("--cell", "cell_m", type=click.FloatRange(0.0, 100.0, min_open=True), default=0.5,
              show_default=True, callback=_finite,
              help="Raster cell size (m). When the cross-validated smoothing kernel is at most "
                   "two cells wide, the floor is rastered on 0.25 m cells instead "
                   "(BuildParams.min_cell_m; the log says so).")
@click.option("--interpolator",
              type=click.Choice(["local_quadratic", "local_linear", "kernel", "linear"]),
              default="local_quadratic", show_default=True,
              help="Kernel-weighted local quadratic, plane or constant (bandwidth, shrinkage "
                   "and ridges chosen by cross-validation over walks), or Delaunay-linear.")
@click.option("--build-time", default=None, callback=_iso_time,
              help="Build time written to the manifest, ISO 8601 (e.g. 2026-11-22T10:00:00Z; "
                   "default: end of the newest walk, so rebuilding the same data gives the same "
                   "bytes).")
@click.option("--plan", "plan_file", default=None,
              type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Build one floor with this floor plan; SOURCE is then any folder of that "
                   "floor's traces and walk plans. GeoJSON in metres (lon/lat with a "
                   "floor_info.json beside it) or a DXF drawing (layers OUTLINE, OBSTACLES, "
                   "WALLS and the like; docs/processing_and_mapping.md).")
@click.option("--dxf-layer", "dxf_layers", multiple=True, metavar="ROLE=LAYER",
              help="With a DXF --plan: a layer of the role outline, obstacle or wall (e.g. "
                   "outline=A-FLOR-OTLN, wall=A-WALL), in place of that role's default names. "
                   "Repeatable.")
@click.option("--floor", "floor_name", default=None,
              help="With --plan: the floor's name as its traces give it (default: the one "
                   "floor of SOURCE's traces); walks that record no floor are this one "
                   "(default: the plan's, its folder's name for a geojson_map.json, else its "
                   "file name).")
@click.option("--exclude", multiple=True, metavar="WALK",
              help="Leave this walk out of the maps: a trace id or a trace file's name (a "
                   "walk plan's walk_id or sensor log), or @FILE with one per line (walks "
                   "held out for `indoormap evaluate`). Repeatable.")
@click.option("--overwrite", is_flag=True, help="Replace existing output bundles.")
def build_command(source: Path, out: Path, store_dir: Path | None, registry_dir: Path | None,
                  cell_m: float, interpolator: str, build_time: str | None,
                  plan_file: Path | None, dxf_layers: tuple[str, ...], floor_name: str | None,
                  exclude: tuple[str, ...], overwrite: bool) -> None:
    """Build map bundles from a floor folder (floor_info.json, geojson_map.json,
    path_data_files/ or walk plans), a site folder of floors, or (with --plan) a folder of
    one floor's traces: ingest, process, level, interpolate, publish atomically. Writes
    OUT/<floor> per floor (rasters, Wi-Fi/BLE fingerprints, device table) and OUT/_site
    (floor model, device table, AP selection report)."""
    from survey.ingest import ingest
    from survey.process_store import process_store
    from survey.progress import progress
    from survey.store import SurveyStore

    from .interpolate import RasterParams

    params = BuildParams(cell_m=cell_m, raster=RasterParams(method=interpolator),
                         build_time=build_time)
    if out.exists() and not out.is_dir():
        raise click.UsageError(f"{out} is a file; -o/--out needs a folder")
    if registry_dir is not None and registry_dir.exists() and not registry_dir.is_dir():
        raise click.UsageError(f"{registry_dir} is a file; --registry needs a folder")
    # `.` or `F1/path_data_files/..` name the folder they lead to (its name is the floor's);
    # made absolute without following links, as the ingest compares the paths it found
    source = Path(os.path.abspath(source))
    layers = dxf_layer_roles(dxf_layers, plan_file)
    if plan_file is None:
        if floor_name is not None:
            raise click.UsageError("--floor names the floor of a --plan build; a floor folder "
                                   "is named by itself")
        floors = floors_of(source)
        inputs = [walks_folder(f) for f in floors]
        floor_names = {folder: f.name for f, folder in zip(floors, inputs)}
        # a bad plan fails before the work; a plan of several floors gives the folder's
        read_from = {f: read_floor_plan(f, level=f.name) for f in floors}
        # by the store's key of the floor: a folder "Level 1" holds walks of "Level_1"
        plans = {floor_key(f.name): plan for f, plan in read_from.items()}
    else:
        if floor_name is not None:
            check_floor_bundle_name(floor_name, "--floor")
        inputs = [source]
        floor_names = {source: floor_name or plan_floor_name(plan_file)}
        plan = read_floor_plan(plan_file, dxf_layers=layers,
                               level=floor_name or plan_floor_name(plan_file))
        if floor_name is not None and plan.floor_name and plan.floor_name != floor_name:
            click.echo(f"warning: {plan_file} says it is the plan of floor "
                       f"{plan.floor_name}; building it as floor {floor_name} (--floor)",
                       err=True)
        read_from = {plan_file: plan}
        plans = {floor_key(floor_name): plan} if floor_name is not None else {}
    for plan_read in read_from.values():
        for repair in plan_read.repairs:
            click.echo(f"warning: {repair}", err=True)
    check_grids(read_from, params)
    site_target = out / SITE_BUNDLE

    def check_targets() -> None:
        for target in [*(out / name for name in plans), site_target]:
            refuse_to_replace(target, overwrite)
            if target.exists() and not (target / "manifest.json").is_file():
                raise PublishError(f"{target} exists and is not a map bundle; --overwrite "
                                   "replaces bundles only, move it away first")
        others = sorted(p.name for p in out.iterdir()
                        if (p / "manifest.json").is_file() and p.name not in plans
                        and p.name != SITE_BUNDLE and not p.name.startswith(".")) \
            if plans and out.is_dir() else []
        if others:
            click.echo(f"warning: {site_target} will model floor{'s' * (len(plans) > 1)} "
                       f"{', '.join(plans)} only; the bundles of {', '.join(others)} in {out} "
                       "stay but drop out of its floor model (build the site folder to model "
                       "every floor)", err=True)

    check_targets()
    excluding = exclude_names(exclude)  # an @FILE is read once
    check_exclude_early(excluding, inputs)
    remove_stale_temporaries(tempfile.gettempdir(), prefix=TMP_STORE_PREFIX)
    with staging_folder(out) as stage, \
            tempfile.TemporaryDirectory(prefix=tmp_prefix(TMP_STORE_PREFIX)) as tmp:
        store_path = store_dir or Path(tmp) / "store"

        def say(msg: str) -> None:
            click.echo(msg, err=True)

        say(f"ingest {', '.join(map(str, inputs))} into {store_path}")
        with progress("ingest", unit="files") as update:
            # walks that record no floor are the folder's (the plan's) floor
            summary = ingest(inputs, store_path, progress=update, floor_names=floor_names)
        for o in summary.failed:
            say(f"  unreadable: {at_path(o.path, str(o.detail))}")
        if summary.bad:
            say(f"  {bad_lines_summary(summary.bad, summary.messages)}")
            for m in summary.messages[1:5]:
                say(f"    then: {m}")
        # an ingest whose every file failed leaves no store it would have created
        store = SurveyStore.open(store_path) if store_path.exists() else None
        cat = store.catalog() if store is not None else pd.DataFrame()
        if cat.empty:
            raise BuildError(f"{', '.join(map(str, inputs))}: no readable walk to build from "
                             f"({len(summary.failed)} unreadable)")
        for folder in floor_names:
            unnamed = ingested_from(cat, summary, folder)
            unnamed = unnamed[(unnamed["floor_name"] == "") & (unnamed["floor_id"] == "")]
            if len(unnamed):
                say(f"  {len(unnamed)} walk(s) in {folder} record no floor: taken as "
                    f"{unnamed['floor'].iloc[0]}")
        if not plans:  # --plan without --floor: the floor of SOURCE's traces
            walks_floor = floor_of_traces(cat, summary, source)
            check_plan_floor(plan, plan_file, cat, summary, source)
            plans = {walks_floor: plan}
            check_targets()
        else:
            for name, folder in zip(plans, inputs):
                check_floor_names(cat, summary, name, folder, say,
                                  planned=plan_file is not None)
        left_out = excluded_walks(cat, summary, inputs, excluding, say, floors=list(plans))
        site = one_site(cat[~cat["trace_id"].isin(list(left_out))], inputs)
        reachable = {(s, fl): plans[fl].reachable for s, fl in
                     cat[["site", "floor"]].drop_duplicates().itertuples(index=False)
                     if fl in plans}
        with progress("process", int(cat["floor"].isin(list(plans)).sum()),
                      unit="walks") as update:
            # only the floors built: the others' plans are not given here (sessions are
            # fitted over the whole store either way)
            report = process_store(store, floors=list(plans), reachable=reachable,
                                   progress=update)
        for warning in report.warnings:
            click.echo(f"warning: {warning}", err=True)
        if report.failed:
            tid, reason = next(iter(report.failed.items()))
            raise BuildError(f"{len(report.failed)} walks of the store cannot be read, e.g. "
                             f"{tid}: {reason}; ingest their files again to repair them")
        source_of = dict(zip(cat["trace_id"], cat["source_path"]))
        for tid, reason in report.skipped.items():
            say(f"  skipped {source_of.get(tid, tid)}: {reason}")
        registry = Registry(registry_dir) if registry_dir else None
        radio = build_site_radio(store, list(plans), site=site, params=params.radio,
                                 exclude_walks=left_out, progress=say)
        site_id, site_build_time, site_walks, done, thin = "", "", [], [], []
        for name, plan in plans.items():
            content = build_floor(store, plan, floor=name, site=site, params=params,
                                  radio=radio, exclude_walks=left_out, progress=say)
            site_id = content.site_id
            site_build_time = max(site_build_time, content.build["build_time"])
            site_walks += content.build["source_walks"]
            bundle_id = write_bundle(stage / name, content)
            cov = content.metrics["coverage"]
            done.append((name, f"{name}: bundle {bundle_id[:16]} -> {out / name} "
                               f"({content.metrics['n_walks']} walks; reachable area within "
                               f"2 m of a sample: {100 * cov['within_2m']:.0f} %)"))
            on_plan = content.metrics["samples_on_plan"]
            if on_plan < SAMPLES_OFF_PLAN_WARNING:
                thin.append(f"warning: {name}: {100 * (1 - on_plan):.0f} % of the surveyed "
                            f"samples lie more than {ON_PLAN_M:g} m outside the plan's "
                            "reachable area; is the plan the whole floor, in the walks' "
                            "frame?")
            raw = content.metrics.get("not_calibrated_walks")
            if raw:
                ids = raw["trace_ids"]
                shown = ", ".join(ids[:3]) + (", ..." if len(ids) > 3 else "")
                thin.append(
                    f"warning: {name}: the magnetic layers are made of {len(ids)} walk(s) whose "
                    f"magnetometer is not calibrated ({shown}), no walk of the floor being "
                    "calibrated: they are off by the phones' hard iron; see `indoormap "
                    "survey-report --store STORE` (calibration, session)"
                    if raw["in_magnetic_layers"] else
                    f"warning: {name}: {len(ids)} walk(s) left out of the magnetic layers, "
                    f"their magnetometer not calibrated ({shown}; `indoormap survey-report "
                    "--store STORE` says why); their radio rows are used")
            if cov["within_2m"] < THIN_COVERAGE:
                thin.append(f"warning: {name}: only {100 * cov['within_2m']:.0f} % of the "
                            "reachable area lies within 2 m of a surveyed sample, so the "
                            "magnetic layers hold no values on most of the floor; survey more "
                            f"walks (`indoormap validate {out / name}` shows the gaps)")
        built_walks = {w["trace_id"] for w in site_walks}
        thin += input_warnings(summary, cat[cat["trace_id"].isin(list(built_walks))])
        site_content = radio.site_content(site_id, build={
            "build_time": site_build_time, "seed": params.seed,
            "source_walks": sorted(site_walks, key=lambda w: w["trace_id"])})
        site_bundle_id = write_bundle(stage / SITE_BUNDLE, site_content)
        fm = site_content.metrics["floor_model"]
        ble_fm = site_content.metrics["ble_floor_model"]
        acc = ("no floor model (no radio rows)" if fm is None else
               f"floor model: {n_floors_text(len(fm['floors']))}, cross-validated per scan "
               + format_share(fm["cv_scan_accuracy"])
               + ("" if ble_fm is None else "; BLE floor model per BLE window "
                  + format_share(ble_fm["cv_scan_accuracy"])))
        done.append((SITE_BUNDLE, f"site: bundle {site_bundle_id[:16]} -> {site_target} "
                                  f"({acc})"))
        # the floors and their site bundle change together, once all are built
        replace_together([(stage / name, out / name) for name, _ in done],
                         overwrite=overwrite)
        seq, dropped = (site_model_floors_dropped(registry, site_id, list(plans))
                        if registry else (0, []))
        for name, line in done:
            click.echo(line)
            if registry and name == SITE_BUNDLE and dropped:
                click.echo(f"warning: not published: the registry's current "
                           f"{site_id}/{SITE_BUNDLE} #{seq} models floors "
                           f"{', '.join(dropped)} too, which this build's floor model would "
                           "drop (build the site folder to replace it, or publish "
                           f"{out / name} with `indoormap bundle publish`)", err=True)
            elif registry:
                try:
                    entry = registry.publish(out / name)
                except RollbackRefused as err:  # the same bytes as an older version
                    click.echo("warning: not made current: "
                               + already_published_text(out / name, registry_dir, err), err=True)
                    continue
                click.echo(f"  published as {site_id}/{name} #{entry['seq']}"
                           + ("; its damaged copy in the registry was replaced"
                              if entry.get("repaired") else ""))
        for warning in thin:
            click.echo(warning, err=True)


def input_warnings(summary: IngestSummary, used: pd.DataFrame, shown: int = 5) -> list[str]:
    """Warnings for the end of a build, where they are read (the ingest's lines scroll away
    above the progress): the input files left out as unreadable, and the walks built with
    bad lines skipped (``used``: their catalog rows), each by name with its reasons."""
    def more(n: int) -> str:
        return f"; {n - shown} more" if n > shown else ""

    out = []
    failed = summary.failed
    if failed:
        out.append(f"warning: {len(failed)} input file(s) unreadable, left out of the maps: "
                   + "; ".join(at_path(o.path, str(o.detail)) for o in failed[:shown])
                   + more(len(failed)))
    damaged = used[used["n_bad_lines"] > 0] if "n_bad_lines" in used else used.iloc[:0]
    if len(damaged):
        def reasons(bad_json: str) -> str:
            return ", ".join(f"{k} {v}" for k, v in sorted(json.loads(bad_json).items()))

        out.append(f"warning: {len(damaged)} walk(s) built with bad lines skipped: "
                   + "; ".join(f"{src} ({reasons(bj)})" for src, bj in
                               zip(damaged["source_path"].head(shown),
                                   damaged["bad_json"].head(shown)))
                   + more(len(damaged)))
    return out


def site_model_floors_dropped(registry: Registry, site_id: str, floors: list[str]
                              ) -> tuple[int, list[str]]:
    """The registry's current site bundle of ``site_id`` (its seq) and the floors it models
    that a new one modelling ``floors`` would not; ``(0, [])`` before any site bundle."""
    cur = registry.current(site_id, SITE_BUNDLE)
    if cur is None:
        return 0, []
    bundle = registry.open(site_id, SITE_BUNDLE, cur["bundle_id"])
    modelled = bundle.manifest["metrics"].get("floors") or []
    return cur["seq"], sorted(set(map(str, modelled)) - set(floors))
