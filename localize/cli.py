"""``indoormap localize`` and ``indoormap evaluate``: run localizers on survey walks.

Both read traces with the survey stage (:mod:`survey.step_summaries`, imported lazily so that
importing this module stays light), pick the floor bundle of each walk (a floor bundle, or a
folder of floor bundles: the walk's floor id decides), and run one of
:data:`localize.baselines.METHODS`.

Start position (``--start``): ``auto`` (the first Wi-Fi/BLE fix of the walk when the bundle has
fingerprints and a scan of the walk can be located, else the walk's first waypoint),
``waypoint`` (first waypoint, as the ILC PDR baseline), ``radio`` (first Wi-Fi/BLE fix, an
error without one), or ``X,Y`` in metres.

A walk that cannot be read or localized is reported (file and reason) and the others go on;
the command then exits with status 1.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import click
import numpy as np

from localize.errors import LocalizationError
from survey.publish import refuse_to_replace

#: Scans of a walk used to calibrate an unknown phone's RSSI online.
ONLINE_CALIBRATION_SCANS = 8


def _open_maps(path: Path):
    """Floor bundles (and the site bundle's floor model) of a bundle or a folder of bundles;
    registry folders (``REG/<site>/<floor>``, ``REG/<site>``) give their current versions."""
    from localize.bundle import is_bundle_dir, load_bundle
    from localize.floor_classifier import FloorClassifier
    from localize.floors import SiteMaps

    if is_bundle_dir(path):
        return SiteMaps([load_bundle(path)])
    subs = [load_bundle(p) for p in sorted(path.iterdir()) if is_bundle_dir(p)]
    if not subs:
        raise LocalizationError(f"{path}: neither a bundle nor a folder of bundles (nor a "
                                "registry's site folder)")
    site = [b for b in subs if b.manifest.get("kind") == "site"]
    model = FloorClassifier.from_bundle(site[0]) if site else None
    return SiteMaps([b for b in subs if b.manifest.get("kind") != "site"], floor_model=model)


_POSITIONERS: dict[tuple[str, str], object] = {}


def _positioner(bundle, kind: str):
    """The bundle's ``kind`` positioner, built once per bundle id (bundles are content-addressed,
    so the cache cannot go stale) rather than once per walk."""
    from localize.fingerprint_positioner import FingerprintPositioner

    key = (bundle.bundle_id, kind)
    if key not in _POSITIONERS:
        if len(_POSITIONERS) >= 16:
            _POSITIONERS.clear()
        _POSITIONERS[key] = FingerprintPositioner.from_bundle(bundle, kind)
    return _POSITIONERS[key]


def radio_for_walk(bundle, device_model: str | None, scans, *, kind: str | None = None
                   ) -> tuple[object | None, str]:
    """The bundle's Wi-Fi (else BLE, or ``kind``) positioner, calibrated for the walk's phone,
    and how.

    A phone model in the bundle's device table (fitted on Wi-Fi) uses its stored ``k, b``; any
    other phone, and BLE, is calibrated online from the first
    :data:`ONLINE_CALIBRATION_SCANS` scans of ``scans`` (same kind). Returns ``(None, "")``
    when the bundle has no fingerprints of that kind.
    """
    pos, kind = next(((p, k) for k in ([kind] if kind else ["wifi", "ble"])
                      if (p := _positioner(bundle, k)) is not None), (None, ""))
    if pos is None:
        return None, ""
    known = pos.for_device(bundle, device_model or "") if kind == "wifi" else None
    if known is not None:
        return known, f"device table ({device_model}: k={known.rssi_k:.3f}, " \
                      f"b={known.rssi_b:+.1f} dB)"
    first = [s for s in (scans or []) if s is not None][:ONLINE_CALIBRATION_SCANS]
    if not first:
        return pos, "uncalibrated (no scan to calibrate from)"
    cal = pos.online_calibration(first)
    return pos.with_calibration(cal.k, cal.b), \
        f"online from {cal.n_scans} scans (k={cal.k:.3f}, b={cal.b:+.1f} dB)"


def _radio_of(bundle, trace, steps):
    return radio_for_walk(bundle, trace.header.model, steps.scans)[0]


def _walks(paths: tuple[str, ...]) -> list[Path]:
    from survey.trace_reader import find_trace_files

    files = find_trace_files(paths)
    if not files:
        raise click.UsageError("no trace files (.txt, .txt.gz) found in the given paths")
    return files


def _parse_start(start: str) -> str | tuple[float, float]:
    """``--start``'s value checked before any walk is read: a keyword or ``(x, y)`` (m)."""
    if start in ("auto", "waypoint", "radio"):
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


def _start(start: str | tuple[float, float], steps, trace, radio
           ) -> tuple[tuple[float, float] | None, str]:
    """Start position and how it was chosen; None = let the localizer use the radio fix."""
    from localize.filter import first_radio_fix
    from survey.step_summaries import waypoints_of

    if not isinstance(start, str):
        return start, "given"
    if start == "radio":
        if radio is None:
            raise LocalizationError("--start radio needs a bundle with Wi-Fi or BLE "
                                    "fingerprints (wifi_rp/wifi_fp tables)")
        return None, "radio"
    how = "first waypoint"
    if start == "auto" and radio is not None:
        if first_radio_fix(radio, steps) is not None:
            return None, "radio"
        how = "first waypoint (no Wi-Fi/BLE fix in the walk)"
    t, xy = waypoints_of(trace)
    if not len(t):
        raise LocalizationError(f"{steps.trace_id}: no waypoint to start from"
                                + (" and no Wi-Fi/BLE fix" if start == "auto" else "")
                                + "; pass --start X,Y")
    return (float(xy[0, 0]), float(xy[0, 1])), how


def _read_walk(path: Path):
    """The trace at ``path``; a warning names the file when lines had to be skipped (bad
    lines, a damaged compressed stream), as ``indoormap ingest`` reports them.

    Raises
    ------
    SurveyFormatError
        The file holds no sensor sample, waypoint or scan (empty, or not a trace file).
    """
    from survey.errors import SurveyFormatError
    from survey.trace_format import bad_lines_summary
    from survey.trace_reader import read_trace

    trace = read_trace(path)
    if trace.is_empty:
        raise SurveyFormatError(trace.empty_reason(), path=str(path), reason="empty")
    r = trace.report
    if r.bad_total:
        click.echo(f"warning: {path}: {bad_lines_summary(r.bad, r.messages)}", err=True)
    return trace


def _warn_if_off_floor(bundle, start_xy: tuple[float, float] | None) -> None:
    """Warn when a given start (m) is off the bundle's reachable area: the particles drawn
    there die at their first move and are re-drawn around it."""
    if start_xy is not None and not bundle.reachable(*start_xy).all():
        g = bundle.grid
        click.echo(f"warning: start {start_xy[0]:g},{start_xy[1]:g} is off the reachable area "
                   f"of {bundle.manifest.get('floor_name') or bundle.floor_id} (x {g.x0_m:g} to "
                   f"{g.x0_m + g.width * g.cell_m:g} m, y {g.y0_m:g} to "
                   f"{g.y0_m + g.height * g.cell_m:g} m)", err=True)


def _warn_if_source_walk(bundle, trace_id: str) -> None:
    """Warn when the bundle was built from this walk (its errors are then optimistic)."""
    if bundle.has_table("source_walks"):
        used = set(bundle.table("source_walks").column("trace_id").to_pylist())
        if trace_id in used:
            click.echo(f"warning: {trace_id} was used to build {bundle.path}; its errors are "
                       "optimistic", err=True)


class _WalkFailures:
    """Walks that could not be read or localized: each is reported with its file and reason,
    and the walks after it still run."""

    def __init__(self) -> None:
        self.count = 0

    def run(self, where: str | Path, fn):
        """``fn()``, or None after reporting an indoormap error (bad trace, no start, ...)
        under ``where`` (the file, and the method when one method failed)."""
        from survey.errors import IndoormapError

        try:
            return fn()
        except IndoormapError as err:
            self.count += 1
            text = str(err)  # reader errors already start with the file
            click.echo(f"error: {text}" if text.startswith(str(where)) else
                       f"error: {where}: {text}", err=True)
            return None

    def exit_if_any(self, total: int) -> None:
        if self.count:
            click.echo(f"{self.count} failure(s) in {total} walk(s)", err=True)
            sys.exit(1)


def plot_track(path: Path, bundle, tracks: dict, waypoints_xy=None, title: str = "", *,
               margin_m: float = 8.0) -> bool:
    """Trajectories over the bundle's reachable mask as a PNG, zoomed to the tracks and
    waypoints (``margin_m`` around them, within the floor): start (circle) and end (square)
    of each track, recoveries (x), waypoints with their order; False without matplotlib."""
    try:  # the object API: no pyplot state, the caller's backend (a notebook's) untouched
        from matplotlib.figure import Figure
    except ImportError:
        return False
    g = bundle.grid
    x1, y1 = g.x0_m + g.width * g.cell_m, g.y0_m + g.height * g.cell_m
    pts = [np.column_stack([np.r_[tr.start.x_m, tr.x_m], np.r_[tr.start.y_m, tr.y_m]])
           for tr in tracks.values()]
    if waypoints_xy is not None and len(waypoints_xy):
        pts.append(np.asarray(waypoints_xy, dtype=float).reshape(-1, 2))
    pts = np.concatenate(pts) if pts else np.empty((0, 2))
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo, hi = np.array([g.x0_m, g.y0_m]), np.array([x1, y1])
    if len(pts):  # every point in view; the margin around them stops at the floor's edge
        p_lo, p_hi = pts.min(axis=0), pts.max(axis=0)
        lo = np.maximum(p_lo - margin_m, np.minimum(lo, p_lo))
        hi = np.minimum(p_hi + margin_m, np.maximum(hi, p_hi))
    span = np.maximum(hi - lo, 1.0)
    fig = Figure(figsize=(8, min(8 * span[1] / span[0], 14) + 0.8))
    ax = fig.subplots()
    ax.imshow(np.asarray(bundle.mask), origin="lower", cmap="Greys", alpha=0.35,
              extent=(g.x0_m, x1, g.y0_m, y1))
    for name, tr in tracks.items():
        xs, ys = np.r_[tr.start.x_m, tr.x_m], np.r_[tr.start.y_m, tr.y_m]
        (line,) = ax.plot(xs, ys, lw=1.2, label=name)
        ax.plot(xs[0], ys[0], "o", color=line.get_color(), ms=7, mfc="none")
        ax.plot(xs[-1], ys[-1], "s", color=line.get_color(), ms=6)
        if tr.n_recoveries:
            ax.plot(tr.x_m[tr.recovered], tr.y_m[tr.recovered], "x", color=line.get_color(),
                    ms=8, label=f"{name}: all particles died, re-drawn")
    if waypoints_xy is not None and len(waypoints_xy):
        ax.plot(waypoints_xy[:, 0], waypoints_xy[:, 1], "k.--", lw=0.6, ms=5, label="waypoints")
        for i, (wx, wy) in enumerate(waypoints_xy):
            ax.annotate(str(i + 1), (wx, wy), textcoords="offset points", xytext=(3, 3),
                        fontsize=6)
    ax.plot([], [], "ko", mfc="none", label="start")
    ax.plot([], [], "ks", label="end")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return True


def _write_track(track, target: Path, fmt: str, overwrite: bool = False) -> None:
    """Write a track table to ``target`` (Parquet or CSV) atomically."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    from survey.publish import atomic_write_bytes

    table = track.to_arrow()
    sink = pa.BufferOutputStream()
    if fmt == "csv":
        pacsv.write_csv(table, sink)
    else:
        pq.write_table(table, sink)
    atomic_write_bytes(target, sink.getvalue().to_pybytes(), overwrite=overwrite)


def _row_name(method: str, smooth: bool) -> str:
    return f"{method}+smoothed" if smooth else method


def _params(particles: int | None):
    from localize.params import FilterParams

    return FilterParams() if particles is None else FilterParams(n_particles=particles)


@click.command("localize")
@click.argument("bundle_path", metavar="BUNDLE",
                type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.argument("walks", nargs=-1, required=True, type=click.Path(exists=True))
@click.option("-o", "--out", "out", required=True, type=click.Path(file_okay=False,
                                                                   path_type=Path),
              help="Output folder: <trace_id>.parquet|csv and <trace_id>.png per walk "
                   "(<trace_id>.smoothed.* with --smooth).")
@click.option("--method", default="indoormap", show_default=True,
              type=click.Choice(["indoormap", "pf_no_mag", "magpp_gaussian", "magicol_dtw",
                                 "pdr", "radio"]))
@click.option("--start", default="auto", show_default=True,
              help="auto (the walk's first Wi-Fi/BLE fix, else its first waypoint), "
                   "waypoint, radio, or X,Y (m).")
@click.option("--particles", type=click.IntRange(1, 1_000_000), default=None,
              help="Particles (default 300).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--format", "fmt", type=click.Choice(["parquet", "csv"]), default="parquet",
              show_default=True)
@click.option("--plot/--no-plot", default=True, show_default=True,
              help="Trajectory PNG over the bundle mask (needs matplotlib).")
@click.option("--smooth", is_flag=True,
              help="Offline: positions from the whole walk, later steps included (particle "
                   "filters only; default: the real-time filter estimates).")
@click.option("--overwrite", is_flag=True, help="Replace a walk's existing outputs in OUT.")
def localize_command(bundle_path: Path, walks: tuple[str, ...], out: Path, method: str,
                     start: str, particles: int | None, seed: int, fmt: str,
                     plot: bool, smooth: bool, overwrite: bool) -> None:
    """Localize survey walks (trace files or folders) on BUNDLE (a floor bundle or a folder
    of floor bundles): positions per step as Parquet/CSV and a trajectory plot.

    A walk that fails (unreadable, no start, another site) is reported with its file and the
    others go on; the exit status is then 1."""
    from localize.baselines import PARTICLE_FILTERS, make_localizer

    if smooth and method not in PARTICLE_FILTERS:
        raise click.BadParameter(f"--smooth needs a particle filter "
                                 f"({', '.join(PARTICLE_FILTERS)}), not {method}")
    from survey.step_summaries import step_summaries, waypoints_of

    start_opt = _parse_start(start)
    maps = _open_maps(bundle_path)
    files = _walks(walks)
    failures = _WalkFailures()
    created = not out.exists()

    def one(f: Path) -> None:
        trace = _read_walk(f)
        name = f"{trace.trace_id}.smoothed" if smooth else trace.trace_id
        target = out / f"{name}.{fmt}"
        png = out / f"{name}.png"
        for existing in (target, png) if plot else (target,):
            refuse_to_replace(existing, overwrite)  # before the work, not after
        steps = step_summaries(trace)
        bundle = maps.select(steps)
        _warn_if_source_walk(bundle, trace.trace_id)
        radio = _radio_of(bundle, trace, steps)
        start_xy, how = _start(start_opt, steps, trace, radio)
        _warn_if_off_floor(bundle, start_xy)
        loc = make_localizer(method, bundle, _params(particles), radio=radio, rng=seed)
        track = loc.run(steps, start_xy=start_xy, smooth=smooth)
        _write_track(track, target, fmt, overwrite=overwrite)
        msg = (f"{trace.trace_id}: {len(track)} {'smoothed ' if smooth else ''}steps on "
               f"{bundle.floor_id} "
               f"({bundle.manifest.get('floor_name', '')}), start {how}, "
               f"{track.n_recoveries} recoveries -> {target}")
        if plot:
            kind = "smoothed offline" if smooth else "real time"
            if plot_track(png, bundle, {method: track}, waypoints_of(trace)[1],
                          title=f"{trace.trace_id} on {bundle.manifest.get('floor_name', '')} "
                                f"({bundle.floor_id[:12]}): {method}, {kind}, start {how}"):
                msg += f", {png.name}"
            else:
                msg += " (no plot: matplotlib not installed)"
        click.echo(msg)

    try:
        for f in files:
            failures.run(f, lambda f=f: one(f))
    finally:
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # nothing was written: leave no empty folder behind
    failures.exit_if_any(len(files))


@click.command("evaluate")
@click.argument("bundle_path", metavar="BUNDLE",
                type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.argument("walks", nargs=-1, required=True, type=click.Path(exists=True))
@click.option("--methods", default="indoormap,pf_no_mag,pdr", show_default=True,
              help="Comma-separated methods.")
@click.option("--start", default="auto", show_default=True,
              help="auto (the walk's first Wi-Fi/BLE fix, else its first waypoint), "
                   "waypoint, radio, or X,Y (m).")
@click.option("--particles", type=click.IntRange(1, 1_000_000), default=None,
              help="Particles of the particle filters (default 300).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="Write the error CDFs as a PNG (folders are created).")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="Write every error as CSV: trace_id, method, waypoint (1 = "
                                 "the walk's first), t_ms, "
                                 "x_m, y_m (the waypoint), est_x_m, est_y_m, error_m.")
@click.option("--smooth", is_flag=True,
              help="Also score every particle filter's offline smoothed track "
                   "(rows '<method>+smoothed').")
@click.option("--overwrite", is_flag=True, help="Replace an existing --plot or --csv file.")
def evaluate_command(bundle_path: Path, walks: tuple[str, ...], methods: str, start: str,
                     particles: int | None, seed: int, plot_path: Path | None,
                     csv_path: Path | None, smooth: bool, overwrite: bool) -> None:
    """Error at the waypoints of walks (median, p80, mean per method). The bundles should be
    built without these walks (a warning names walks the bundle was built from).

    A walk that cannot be read, or a method that fails on a walk, is reported with the file
    (and method) and the rest goes on; the exit status is then 1."""
    from localize.baselines import METHODS, PARTICLE_FILTERS, make_localizer
    from localize.evaluate import summarize, waypoint_errors
    from survey.step_summaries import step_summaries, waypoints_of

    names = [m.strip() for m in methods.split(",") if m.strip()]
    if not names:
        raise click.BadParameter(f"no method given; known: {', '.join(sorted(METHODS))}",
                                 param_hint="--methods")
    unknown = [m for m in names if m not in METHODS]
    if unknown:
        raise click.BadParameter(f"unknown methods {unknown}; known: {sorted(METHODS)}")
    for target in (plot_path, csv_path):
        if target is not None:
            refuse_to_replace(target, overwrite)  # before the work
    start_opt = _parse_start(start)
    maps = _open_maps(bundle_path)
    files = _walks(walks)
    failures = _WalkFailures()
    rows = [(m, False) for m in names] + [(m, True) for m in names
                                          if smooth and m in PARTICLE_FILTERS]
    errors: dict[str, list[np.ndarray]] = {_row_name(m, sm): [] for m, sm in rows}
    table: list[dict] = []  # one row per method and waypoint, for --csv

    def one(f: Path) -> None:
        trace = _read_walk(f)
        t_wp, xy_wp = waypoints_of(trace)
        if len(t_wp) == 0:
            click.echo(f"{f}: no waypoints, skipped", err=True)
            return
        steps = step_summaries(trace)
        bundle = maps.select(steps)
        _warn_if_source_walk(bundle, trace.trace_id)
        radio = _radio_of(bundle, trace, steps)
        start_xy, _ = _start(start_opt, steps, trace, radio)
        _warn_if_off_floor(bundle, start_xy)
        for m, sm in rows:  # a method failing on this walk leaves the others' rows alone
            def run(m=m, sm=sm):
                loc = make_localizer(m, bundle, _params(particles), radio=radio, rng=seed)
                track = loc.run(steps, start_xy=start_xy, smooth=sm)
                err = waypoint_errors(track, t_wp, xy_wp)
                errors[_row_name(m, sm)].append(err)
                est = track.at(t_wp)
                table.extend({"trace_id": trace.trace_id, "method": _row_name(m, sm),
                              "waypoint": i + 1, "t_ms": int(t_wp[i]), "x_m": xy_wp[i, 0],
                              "y_m": xy_wp[i, 1], "est_x_m": est[i, 0], "est_y_m": est[i, 1],
                              "error_m": err[i]} for i in range(len(err)))
            failures.run(f"{f} ({_row_name(m, sm)})", run)

    for f in files:
        failures.run(f, lambda f=f: one(f))
    if not table:
        click.echo("no walk was evaluated", err=True)
        failures.exit_if_any(len(files))
        sys.exit(1)  # every walk lacked waypoints
    n_walks = len({r["trace_id"] for r in table})
    click.echo(f"{'method':<20}{'n':>6}{'median':>9}{'p80':>9}{'mean':>9}  (m, at the "
               f"waypoints of {n_walks} walk(s))")
    for m, v in errors.items():
        s = summarize(np.concatenate(v) if v else np.empty(0))
        click.echo(f"{m:<20}{s['n']:>6}{s['median']:>9.2f}{s['p80']:>9.2f}{s['mean']:>9.2f}")
    if csv_path is not None:
        import pyarrow as pa
        import pyarrow.csv as pacsv

        from survey.publish import atomic_write_bytes

        sink = pa.BufferOutputStream()
        pacsv.write_csv(pa.Table.from_pylist(table), sink)
        csv_path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(csv_path, sink.getvalue().to_pybytes(), overwrite=overwrite)
        click.echo(f"errors: {csv_path}", err=True)
    if plot_path is not None:
        from localize.evaluate import plot_cdfs

        plot_path.parent.mkdir(parents=True, exist_ok=True)
        title = (f"{bundle_path.name}: {n_walks} walk(s), start {start}"
                 + (f", {failures.count} failure(s)" if failures.count else ""))
        if not plot_cdfs(plot_path, {m: np.concatenate(v) for m, v in errors.items() if v},
                         title=title):
            click.echo("(no plot: matplotlib not installed)", err=True)
    failures.exit_if_any(len(files))


def main() -> None:  # pragma: no cover - convenience entry for python -m localize.cli
    from survey.cli import main as indoormap_main

    sys.exit(indoormap_main())
