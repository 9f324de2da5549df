"""``indoormap localize`` and ``indoormap evaluate``: run localizers on survey walks.

Both read traces with the survey stage (:mod:`survey.step_summaries`, imported lazily so that
importing this module stays light), pick the floor bundle of each walk (a floor bundle, or a
folder of floor bundles: the walk's floor id decides), and run one of
:data:`localize.methods.METHODS`.

Radio (:func:`localize.walk_radio.walk_radio`): the bundle's Wi-Fi fingerprints when a Wi-Fi
scan of the walk can be located, else its BLE fingerprints when a BLE window of the walk can
(a walk without Wi-Fi scans; BLE fixes are about twice as far off), for the start and the
radio updates alike.

Start position (``--start``): ``auto`` (the first radio fix of the walk, Wi-Fi else BLE as
above, else the walk's first waypoint), ``waypoint`` (first waypoint, as the ILC PDR
baseline), ``radio`` (first radio fix, an error without one), or ``X,Y`` in metres.

Walks are trace files, or the walks of walk plans (``.geojson``, :mod:`survey.walkline`). A
walk that cannot be read or localized is reported (file and reason) and the others go on;
the command then exits with status 1.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import click
import numpy as np

from localize.cli_common import (AliasedOption, FloorChoices, SeenWalks, TraceIds,
                                  WalkFailures, each_walk, refuse_output_inside_data,
                                  trace_files, waypoint_errors_quietly)
from localize.errors import LocalizationError
from localize.methods import METHODS, SMOOTHABLE
from localize.params import MAX_PARTICLES
from survey.publish import refuse_to_replace

if TYPE_CHECKING:
    from survey.trace_format import Trace

START_HELP = ("auto (the walk's first Wi-Fi fix; for a walk without one, its first BLE fix; "
              "else its first waypoint), waypoint, radio, or X,Y (m).")
PARTICLES_HELP = "Particles of the particle filters (default 300)."
COMPASS_OPTION = click.option(
    "--compass", type=click.Choice(["auto", "as-logged"]), default="auto", show_default=True,
    help="auto: a walk whose step track fits its radio fixes only turned by 60 deg or more "
         "(a phone held in landscape, a rotation vector in another frame) has its compass "
         "turned so, with a warning; as-logged: warned, not turned.")
#: Method names of ``evaluate --method`` (comma-separated, or the option repeated).
DEFAULT_EVALUATE_METHODS = ("auto", "indoormap", "align", "pf_no_mag", "pdr")


def _method_names(values: tuple[str, ...]) -> list[str]:
    """``evaluate --method``'s values (each a name or a comma-separated list), in order, each
    once; a usage error for none or an unknown one."""
    names = list(dict.fromkeys(m.strip() for v in values for m in v.split(",") if m.strip()))
    if not names:
        raise click.BadParameter(f"no method given; known: {', '.join(sorted(METHODS))}",
                                 param_hint="--method")
    unknown = [m for m in names if m not in METHODS]
    if unknown:
        raise click.BadParameter(f"unknown methods {unknown}; known: {sorted(METHODS)}",
                                 param_hint="--method")
    return names


def _parse_start(start: str) -> str | tuple[float, float]:
    """``--start``'s value checked before any walk is read: a keyword or ``(x, y)`` (m)."""
    from localize.start import START_POLICIES

    if start in START_POLICIES:
        return start
    try:
        x, y = (float(v) for v in start.split(","))
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError("not finite")
    except ValueError as err:
        raise click.BadParameter(f"must be auto, waypoint, radio or X,Y (finite, m); got "
                                 f"{start!r}",
                                 param_hint="--start") from err
    return x, y


def _start_of(start_opt: str | tuple[float, float], wr, waypoints_xy
              ) -> tuple[tuple[float, float] | None, str]:
    """:func:`localize.start.start_position` for the walk's radio ``wr``
    (:class:`localize.walk_radio.WalkRadio`), its errors naming the option to change, and a
    start at a BLE fix saying why BLE."""
    from localize.start import start_position

    try:
        xy, how = start_position(start_opt, wr.steps, wr.radio, waypoints_xy,
                                 radio_name=wr.fix_name or "Wi-Fi")
    except LocalizationError as err:
        given = start_opt if isinstance(start_opt, str) else "X,Y"
        raise LocalizationError(f"{err} (--start {given})") from err
    if wr.kind == "ble":  # why BLE, at a BLE start or for the fixes after a given one
        how += f" ({wr.reason})" if xy is None else f"; BLE fixes ({wr.reason})"
    return xy, how


def _warn_if_off_floor(bundle, start_xy: tuple[float, float] | None) -> None:
    """Warn when a given start (m) is off the bundle's reachable area: the particles drawn
    there die at their first move and are re-drawn around it (not when it is so far off that
    the localizer refuses it: that error says so)."""
    from localize.filter import within_reach

    if start_xy is not None and not bundle.reachable(*start_xy).all() \
            and within_reach(bundle.grid, *start_xy):
        g = bundle.grid
        click.echo(f"warning: start {start_xy[0]:g},{start_xy[1]:g} is off the reachable area "
                   f"of {bundle.manifest.get('floor_name') or bundle.floor_id} (x {g.x0_m:g} to "
                   f"{g.x1_m:g} m, y {g.y0_m:g} to {g.y1_m:g} m)", err=True)


def _warn_if_outside_map(bundle, trace_id: str, waypoints_xy: np.ndarray) -> None:
    """Warn when waypoints (m, shape (W, 2)) lie where the bundle's strength layer has no
    data (no survey walk passed near): errors there measure a place the map does not cover,
    where the radio fixes snap to the nearest surveyed area."""
    if "strength" not in bundle.layers or not len(waypoints_xy):
        return
    off = ~np.isfinite(bundle.sample("strength", waypoints_xy[:, 0], waypoints_xy[:, 1]))
    if off.any():
        reach = (((bundle.manifest.get("build") or {}).get("params") or {}).get("raster")
                 or {}).get("max_distance_m")
        near = f"within {reach:g} m" if isinstance(reach, (int, float)) else "near"
        click.echo(f"warning: {int(off.sum())} of {len(off)} waypoints of {trace_id} lie where "
                   f"{bundle.path} has no map data (no survey sample {near}): its errors there "
                   "measure a place the map does not cover", err=True)


def _write_table(table, target: Path, fmt: str, overwrite: bool = False) -> None:
    """Write an Arrow table to ``target`` (Parquet or CSV) atomically."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    from survey.publish import atomic_write_bytes

    sink = pa.BufferOutputStream()
    if fmt == "csv":
        pacsv.write_csv(table, sink)
    else:
        pq.write_table(table, sink)
    atomic_write_bytes(target, sink.getvalue().to_pybytes(), overwrite=overwrite)


def _prepare_walk(trace, maps, start_opt: str | tuple[float, float], waypoints_xy,
                  floors_said: FloorChoices, compass: str = "auto"):
    """What both commands do before localizing a walk: its steps, its floor's bundle (the
    header's floor, else the site's Wi-Fi floor model, else its BLE floor model:
    :meth:`localize.floors.SiteMaps.choose`, said on standard error by ``floors_said`` when a
    model chose), the
    radio model for its phone (Wi-Fi, else BLE: :func:`localize.walk_radio.walk_radio`; the
    steps then carry the walk's BLE windows), and its start (with a warning when it is off the
    floor), with its compass turned where its step track fits its radio fixes only turned
    (``compass`` ``"auto"``; :mod:`localize.compass_check`, said either way). Returns
    ``(wr, bundle, start_xy, how)``, ``wr`` the
    :class:`~localize.walk_radio.WalkRadio` (its ``steps`` and ``radio`` are what to localize
    with); ``how`` names BLE and why when BLE is used."""
    from localize.compass_check import compass_turn
    from localize.maps import mean_heading_offset_deg
    from localize.walk_radio import walk_radio
    from survey.step_summaries import ble_scans_of, step_summaries

    steps = step_summaries(trace)
    ble = ble_scans_of(trace, maps.ble_window_ms)  # as the bundles' BLE was grouped
    bundle, chosen = maps.choose(steps.trace_id, steps.site_id, steps.floor_id,
                                 steps.floor_name, steps.scans, ble,
                                 device_model=trace.header.model or "")
    floors_said.say(trace.trace_id, bundle, chosen)
    wr = walk_radio(bundle, trace.header.model, steps, ble)
    start_xy, how = _start_of(start_opt, wr, waypoints_xy)
    _warn_if_off_floor(bundle, start_xy)
    check = compass_turn(wr.steps, wr.radio, mean_heading_offset_deg(bundle))
    if check is not None and check.turned:
        if compass == "auto":
            wr = dataclasses.replace(wr, steps=check.mended(wr.steps))
        click.echo(f"warning: {trace.trace_id}: {check.sentence()}; "
                   + ("its compass is turned so (--compass as-logged keeps it)"
                      if compass == "auto" else "kept as logged (--compass as-logged)"),
                   err=True)
    return wr, bundle, start_xy, how


def _row_name(method: str, smooth: bool) -> str:
    return f"{method}+smoothed" if smooth else method


def _params(particles: int | None):
    from localize.params import FilterParams

    return FilterParams() if particles is None else FilterParams(n_particles=particles)


@click.command("localize")
@click.argument("bundle_path", metavar="BUNDLE",
                type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.argument("walks", nargs=-1, required=True, type=click.Path())
@click.option("-o", "--out", "out", required=True, type=click.Path(file_okay=False,
                                                                   path_type=Path),
              help="Output folder: <trace_id>.parquet|csv and <trace_id>.png per walk "
                   "(<trace_id>.smoothed.* with --smooth; an id that is no safe file name, "
                   "such as a/b, is made one and given 8 hex digits of its hash).")
@click.option("--method", default="auto", show_default=True,
              type=click.Choice(list(METHODS)),
              help="auto: the particle filter (indoormap), guided by the walk alignment, on "
                   "a floor whose magnetic map predicts walks it did not see, else align; the "
                   "filter on the fixes for bundles that do not record it (the choice is "
                   "printed).")
@click.option("--start", default="auto", show_default=True, help=START_HELP)
@click.option("--particles", type=click.IntRange(1, MAX_PARTICLES), default=None,
              help=PARTICLES_HELP)
@click.option("--seed", type=int, default=0, show_default=True)
@COMPASS_OPTION
@click.option("--format", "fmt", type=click.Choice(["parquet", "csv"]), default="parquet",
              show_default=True)
@click.option("--plot/--no-plot", default=True, show_default=True,
              help="Trajectory PNG per walk in OUT, over the bundle mask (needs matplotlib).")
@click.option("--smooth", is_flag=True,
              help="Offline: positions from the whole walk, later steps included (particle "
                   "filters and align; default: the real-time estimates). wifi-locate's "
                   "--smoothing walk|forward is the same choice for radio fixes alone.")
@click.option("--overwrite", is_flag=True,
              help="Replace a walk's outputs of an earlier run in OUT: its table in either "
                   "format and its plot (one not made this run is removed).")
def localize_command(bundle_path: Path, walks: tuple[str, ...], out: Path, method: str,
                     start: str, particles: int | None, seed: int, compass: str, fmt: str,
                     plot: bool, smooth: bool, overwrite: bool) -> None:
    """Localize survey walks (trace files, walk plans or folders) on BUNDLE (a floor bundle
    or a folder of floor bundles): positions per step as Parquet/CSV and a trajectory plot.

    A walk that fails (unreadable, no start, another site) is reported with its file and the
    others go on; the exit status is then 1."""
    import pyarrow as pa

    from localize.baselines import make_localizer
    from localize.floors import SiteMaps
    from localize.plots import plot_track

    if smooth and method not in SMOOTHABLE:
        raise click.BadParameter(f"--smooth needs a method that can locate a walk offline "
                                 f"({', '.join(SMOOTHABLE)}), not {method}")
    from survey.step_summaries import waypoints_of
    from localize.names import file_stem

    start_opt = _parse_start(start)
    refuse_output_inside_data(out)
    failures = WalkFailures()
    files = trace_files(walks, failures)  # a mistyped path is said before the bundles load
    maps = SiteMaps.open(bundle_path)
    floors_said, in_build = FloorChoices(), SeenWalks()
    created = not out.exists()

    seen = TraceIds()

    def one(where: str, trace: Trace) -> None:
        seen.claim(trace.trace_id, where)
        name = file_stem(trace.trace_id) + (".smoothed" if smooth else "")
        target = out / f"{name}.{fmt}"
        png = out / f"{name}.png"
        # the walk's outputs of any run (either format, the plot): all are replaced, so
        # that an earlier run's table or plot is not left beside this run's
        earlier = [out / f"{name}.{ext}" for ext in ("parquet", "csv", "png")]
        for existing in earlier:
            refuse_to_replace(existing, overwrite)  # before the work, not after
        t_wp, xy_wp = waypoints_of(trace)
        wr, bundle, start_xy, how = _prepare_walk(trace, maps, start_opt, xy_wp, floors_said,
                                                  compass)
        loc = make_localizer(method, bundle, _params(particles), radio=wr.radio, rng=seed,
                             magnetometer=wr.steps.has_magnetometer)
        track = loc.run(wr.steps, start_xy=start_xy, smooth=smooth)
        try:  # scoring is a by-product here: the track is written whatever its waypoints
            err = waypoint_errors_quietly(track, t_wp, xy_wp) if len(t_wp) else np.empty(0)
        except LocalizationError as refused:
            click.echo(f"warning: {where}: track not scored: {refused}", err=True)
            err = np.empty(0)
        err = err[np.isfinite(err)]  # the walk's recorded waypoints, where it has them
        scored = (f"error at its {len(err)} waypoints median {np.median(err):.1f} m, max "
                  f"{err.max():.1f} m" + (" (waypoint times at a steady pace)" * paced(trace))
                  if len(err) else "")
        ran, used, choice = loc.label, method, loc.auto_choice
        if choice is not None:  # what ran (the guide needs a radio fix to start from)
            used = f"auto: {ran}, as {choice.why}"
            if choice.guided and not loc.guided:
                used += (" (not guided: a given start)" if start_xy is not None
                         else " (not guided: no radio model)")
        table = track.to_arrow()
        if fmt == "csv":  # a CSV has no metadata: the walk, floor, method, what ran and
            # the bundle as columns
            for i, (column, value) in enumerate((("trace_id", track.trace_id),
                                                 ("floor_id", track.floor_id),
                                                 ("method", track.method),
                                                 ("ran", ran),
                                                 ("bundle_id", bundle.bundle_id))):
                table = table.add_column(i, column, pa.array([str(value)] * len(table)))
        _write_table(table, target, fmt, overwrite=overwrite)
        # an earlier run's other outputs go now: a plot that then fails leaves none of them
        stale = [p for p in earlier if p != target and (p.is_file() or p.is_symlink())]
        for p in stale:
            p.unlink()
        msg = (f"{trace.trace_id}: {len(track)} {'smoothed ' if smooth else ''}steps on "
               f"{bundle.floor_id} "
               f"({bundle.manifest.get('floor_name', '')}) by {used}, start {how}, "
               f"{track.n_recoveries} recoveries" + (f", {scored}" if scored else "")
               + f" -> {target}")
        if plot:
            kind = "smoothed offline" if smooth else "real time"
            if plot_track(png, bundle, {ran: track}, xy_wp,
                          title=f"{trace.trace_id} on {bundle.manifest.get('floor_name', '')} "
                                f"({bundle.floor_id[:12]}): {ran}, {kind}, start {how}"
                                + (f"\n{scored}" if scored else "")):
                msg += f", {png.name}"
                stale = [p for p in stale if p != png]  # replaced, not removed
            else:
                msg += " (no plot: matplotlib not installed)"
        if stale:
            msg += f" (removed the earlier run's {', '.join(p.name for p in stale)})"
        in_build.check(bundle, trace.trace_id)  # a walk that failed is not counted
        click.echo(msg)

    try:
        total = each_walk(files, failures, one)
    finally:
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # nothing was written: leave no empty folder behind
    in_build.finish()
    failures.exit_if_any(total)


@click.command("evaluate")
@click.argument("bundle_path", metavar="BUNDLE",
                type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.argument("walks", nargs=-1, required=True, type=click.Path())
@click.option("--method", "--methods", "methods", cls=AliasedOption, old_names=("--methods",),
              multiple=True, default=DEFAULT_EVALUATE_METHODS, metavar="METHOD[,METHOD...]",
              show_default=True,
              help=f"Methods to score, comma-separated or the option repeated: "
                   f"{', '.join(METHODS)}.")
@click.option("--start", default="auto", show_default=True, help=START_HELP)
@click.option("--particles", type=click.IntRange(1, MAX_PARTICLES), default=None,
              help=PARTICLES_HELP)
@click.option("--seed", type=int, default=0, show_default=True)
@COMPASS_OPTION
@click.option("--plot-file", "--plot", "plot_path", cls=AliasedOption, old_names=("--plot",),
              type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="FILE",
              help="Write the error CDFs as a PNG to FILE (folders are created).")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="Write every error as CSV: trace_id, method, ran (what the "
                                 "method ran: auto's choice), waypoint (1 = the walk's "
                                 "first), t_ms, x_m, y_m (the waypoint), est_x_m, est_y_m, "
                                 "error_m.")
@click.option("--smooth", is_flag=True,
              help="Also score the offline track of every method that has one (particle "
                   "filters and align; rows '<method>+smoothed'), as localize --smooth "
                   "writes it.")
@click.option("--overwrite", is_flag=True,
              help="Replace an existing --plot-file or --csv file.")
def evaluate_command(bundle_path: Path, walks: tuple[str, ...], methods: tuple[str, ...],
                     start: str, particles: int | None, seed: int, compass: str,
                     plot_path: Path | None,
                     csv_path: Path | None, smooth: bool, overwrite: bool) -> None:
    """Error at the waypoints of WALKS (trace files, walk plans or folders) on BUNDLE (a
    floor bundle or a folder of floor bundles), median, p80 and mean per method. The bundles
    should be built without these walks (a warning names walks the bundle was built from).

    A walk that cannot be read, or a method that fails on a walk, is reported with the file
    (and method) and the rest goes on; the exit status is then 1."""
    from localize.baselines import make_localizer
    from localize.evaluate import summarize
    from localize.floors import SiteMaps
    from survey.step_summaries import waypoints_of

    names = _method_names(methods)
    if plot_path is not None and plot_path.suffix.lower() != ".png":
        raise click.BadParameter(f"{plot_path}: the plot is a PNG; name it .png",
                                 param_hint="--plot-file")
    if plot_path is not None and csv_path is not None and \
            plot_path.resolve() == csv_path.resolve():
        raise click.BadParameter("--plot-file and --csv name the same file",
                                 param_hint="--plot-file")
    for target, suffix, option in ((plot_path, ".png", "--plot-file"),
                                   (csv_path, ".csv", "--csv")):
        if target is not None:
            refuse_output_inside_data(target, option)  # a file there damaged a bundle
            refuse_to_replace(target, overwrite, suffixes=(suffix,))  # before the work
    start_opt = _parse_start(start)
    failures = WalkFailures()
    files = trace_files(walks, failures)  # a mistyped path is said before the bundles load
    maps = SiteMaps.open(bundle_path)
    floors_said, in_build = FloorChoices(), SeenWalks()
    rows = [(m, False) for m in names] + [(m, True) for m in names
                                          if smooth and m in SMOOTHABLE]
    errors: dict[str, list[np.ndarray]] = {_row_name(m, sm): [] for m, sm in rows}
    table: list[dict] = []  # one row per method and waypoint, for --csv
    evaluated: set[str] = set()  # walks with at least one method's errors
    ran: dict[str, set[str]] = {}  # what each row ran ("auto": what it chose per bundle)

    seen = TraceIds()
    paced_walks: set[str] = set()  # walk-line walks timed by start_ms/end_ms only

    def one(where: str, trace: Trace) -> None:
        seen.claim(trace.trace_id, where)
        t_wp, xy_wp = waypoints_of(trace)
        if len(t_wp) == 0:
            click.echo(f"{where}: no waypoints, skipped", err=True)
            return
        if paced(trace):
            paced_walks.add(trace.trace_id)
        wr, bundle, start_xy, how = _prepare_walk(trace, maps, start_opt, xy_wp, floors_said,
                                                  compass)
        _warn_if_outside_map(bundle, trace.trace_id, xy_wp)
        if start_opt == "auto" and how.startswith("first waypoint"):  # fell back to the truth
            click.echo(f"note: {trace.trace_id}: start {how}: its errors start from the "
                       "truth, as a user's could not", err=True)
        elif wr.kind == "ble":  # the scores of this walk are BLE's, not Wi-Fi's
            click.echo(f"{trace.trace_id}: start {how}", err=True)
        for m, sm in rows:  # a method failing on this walk leaves the others' rows alone
            def run(m=m, sm=sm):
                loc = make_localizer(m, bundle, _params(particles), radio=wr.radio, rng=seed,
                                     magnetometer=wr.steps.has_magnetometer)
                track = loc.run(wr.steps, start_xy=start_xy, smooth=sm)
                err = waypoint_errors_quietly(track, t_wp, xy_wp)
                errors[_row_name(m, sm)].append(err)
                label = loc.label
                ran.setdefault(_row_name(m, sm), set()).add(label)
                evaluated.add(trace.trace_id)
                if csv_path is not None:
                    est = track.at(t_wp)
                    table.extend({"trace_id": trace.trace_id, "method": _row_name(m, sm),
                                  "ran": label,
                                  "waypoint": i + 1, "t_ms": int(t_wp[i]), "x_m": xy_wp[i, 0],
                                  "y_m": xy_wp[i, 1], "est_x_m": est[i, 0],
                                  "est_y_m": est[i, 1], "error_m": err[i]}
                                 for i in range(len(err)))
            failures.run(f"{where} ({_row_name(m, sm)})", run)
        if trace.trace_id in evaluated:  # scored by some method: its scores are in-sample
            in_build.check(bundle, trace.trace_id)

    total = each_walk(files, failures, one)
    in_build.finish()
    if not evaluated:
        click.echo("no walk was evaluated", err=True)
        failures.exit_if_any(total)
        sys.exit(1)  # every walk lacked waypoints
    n_walks = len(evaluated)
    # auto is labelled with what it ran ("auto (align)"): its rows and curve equal that
    # method's when both are asked for
    label = {m: f"{m} ({', '.join(sorted(ran[m]))})" if m.split("+")[0] == "auto" and m in ran
             else m for m in errors}
    w = max([20, *(len(v) + 2 for v in label.values())])  # "magpp_gaussian+smoothed": 23
    click.echo(f"{'method':<{w}}{'n':>6}{'median':>9}{'p80':>9}{'mean':>9}  (m, at the "
               f"waypoints of {n_walks} walk(s))")
    for m, v in errors.items():
        s = summarize(np.concatenate(v) if v else np.empty(0))
        click.echo(f"{label[m]:<{w}}{s['n']:>6}{s['median']:>9.2f}{s['p80']:>9.2f}"
                   f"{s['mean']:>9.2f}")
    if paced_walks & evaluated:
        click.echo(f"note: {len(paced_walks & evaluated)} of the {n_walks} walks give start_ms "
                   "and end_ms, not vertex times: their waypoint times are spread at a steady "
                   "pace along the line, so their errors include the walkers' changes of pace",
                   err=True)
    if csv_path is not None:
        import pyarrow as pa

        _write_table(pa.Table.from_pylist(table), csv_path, "csv", overwrite=overwrite)
        click.echo(f"errors: {csv_path}", err=True)
    if plot_path is not None:
        from localize.plots import plot_cdfs

        plot_path.parent.mkdir(parents=True, exist_ok=True)
        title = (f"{bundle_path.name}: {n_walks} walk(s), start {start}"
                 + (f", {failures.count} failure(s)" if failures.count else "")
                 + (f"; {in_build.count} of the walks seen by the map (errors better than "
                    "unseen walks')" if in_build.count else ""))
        if plot_cdfs(plot_path, {label[m]: np.concatenate(v) for m, v in errors.items() if v},
                     title=title):
            click.echo(f"plot: {plot_path}", err=True)
        else:
            click.echo("(no plot: matplotlib not installed)", err=True)
    failures.exit_if_any(total)


def paced(trace: Trace) -> bool:
    """Whether a walk's waypoint times are its walk plan's start and end spread at a steady
    pace (:data:`survey.walkline.PACED`), not clicks."""
    from survey.walkline import PACED, WAYPOINT_TIMES

    return trace.header.extra.get(WAYPOINT_TIMES) == PACED


def main() -> None:  # pragma: no cover - convenience entry for python -m localize.cli
    from survey.cli import main as indoormap_main

    sys.exit(indoormap_main())
