"""``indoormap floor`` and ``indoormap wifi-locate``: the radio maps of bundles applied to walks.

Both print CSV on standard output, each walk's rows as soon as the walk is through (progress
and notes on standard error); a walk that fails (unreadable, of another site, or without a
result: no scan of the kind, or none that hears a transmitter the maps know) prints no rows and
is reported with its file and reason, the others go on, and the exit code is then 1. Walks
are trace files or the walks of walk plans (their Wi-Fi and BLE logs):

- ``floor SITE_BUNDLE WALK...``: per scan ``level=scan`` rows (floor of the scan alone and of the
  last ``--window`` scans) and one ``level=walk`` row per walk (all its scans), with the floor
  the trace file names (``recorded_floor``) for checking and the model used (``kind``): by
  default the Wi-Fi floor model when it classifies one of the walk's Wi-Fi scans, else the
  BLE floor model over the walk's BLE windows (``--kind wifi|ble`` forces one).
- ``wifi-locate BUNDLE WALK...``: per scan the Wi-Fi (or BLE) position, its spread, the number
  of transmitters the bundle knows and, when the walk has waypoints, the distance to the
  waypoint track interpolated in time at the scan (``error_m``). By default each walk's scans
  are matched together (``--smoothing walk``; ``forward`` uses only earlier scans, ``none``
  none).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

import click
import numpy as np

from localize.cli_common import (FloorChoices, SeenWalks, TraceIds, WalkFailures,
                                  each_walk, trace_files)
from localize.errors import LocalizationError
from localize.floors import ble_window_ms, device_table, walk_floor_index
from localize.names import floor_key
from localize.rssi_calibration import checked_rssi_calibration

if TYPE_CHECKING:
    from survey.trace_format import Trace


def _scans(trace, kind: str, ble_window_ms: int):
    """Wi-Fi scans with every row and its age (the floor model was fitted on rows of any age;
    the fingerprint matcher down-weights old rows), or BLE windows of ``ble_window_ms``."""
    from survey.step_summaries import ble_scans_of, scans_of

    return scans_of(trace) if kind == "wifi" else ble_scans_of(trace, ble_window_ms)


def _site_bundle(path: Path):
    from localize.bundle import is_bundle_dir, load_bundle

    from mapping.registry import SITE_BUNDLE

    for cand in (path, path / SITE_BUNDLE):
        if is_bundle_dir(cand):
            b = load_bundle(cand)
            if b.manifest.get("kind") == "site":
                return b
    raise LocalizationError(f"{path}: not a site bundle (nor a folder holding {SITE_BUNDLE}/); "
                            "`indoormap build` writes one beside the floor bundles")


class _CsvRows:
    """CSV on standard output: the header at once, then each walk's rows as soon as the walk
    is through (a long run shows its results as it goes; a walk that fails prints none)."""

    def __init__(self, columns: list[str]) -> None:
        import csv

        self._writer = csv.DictWriter(sys.stdout, fieldnames=columns, lineterminator="\n",
                                      extrasaction="ignore")
        self._writer.writeheader()

    def write(self, rows: list[dict]) -> None:
        for r in rows:
            self._writer.writerow({k: (f"{v:.3f}" if isinstance(v, float) else v)
                                   for k, v in r.items()})
        sys.stdout.flush()


@click.command("floor")
@click.argument("site_path", metavar="SITE_BUNDLE",
                type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.argument("walks", nargs=-1, required=True, type=click.Path())
@click.option("--window", type=click.IntRange(1, 1000), default=5, show_default=True,
              help="Scans in the sequence estimate (this scan and the ones before it).")
@click.option("--kind", type=click.Choice(["auto", "wifi", "ble"]), default="auto",
              show_default=True,
              help="Floor model to use: auto = the Wi-Fi model over the walk's Wi-Fi scans when "
                   "it classifies one of them, else the BLE model over its 2 s BLE windows "
                   "(what localize does for a walk that names no floor); wifi or ble: that "
                   "model only.")
def floor_command(site_path: Path, walks: tuple[str, ...], window: int, kind: str) -> None:
    """Predicted floor per scan and per walk (CSV) from the site bundle's floor models.

    The site bundle holds a Wi-Fi floor model (or a BLE one when the survey had no Wi-Fi) and,
    when the survey had BLE on two floors or more, a BLE floor model beside it. With --kind
    auto a walk whose Wi-Fi scans the Wi-Fi model classifies is put on a floor by Wi-Fi, any
    other walk (no Wi-Fi: an iPhone logs BLE only) by the BLE model over its BLE windows.

    \b
    CSV columns (stdout; a summary on stderr):
      level           scan, or walk (one row after each walk's scans)
      trace_id, t_ms  the walk; the scan's time (Unix ms; empty on walk rows)
      n_known         scan: transmitters it hears that the model knows;
                      walk: scans that hear any
      floor           the scan's most likely floor; on walk rows the walk's, as localize
                      decides it (the floor most Wi-Fi scans are on; BLE: summed)
      p_floor         the scan's probability of that floor (0-1)
      window_floor    most likely floor over the scan and the WINDOW-1 before it
      recorded_floor  the floor the trace file names (empty if none)
      kind            the model used: wifi (scans) or ble (BLE windows)
    """
    from localize.bundle import bundle_dirs, is_bundle_dir
    from localize.floor_classifier import site_floor_models
    from localize.floors import SiteMaps, unknown_phone_calibration

    from mapping.registry import SITE_BUNDLE

    site = _site_bundle(site_path)
    models = site_floor_models(site)
    if not models:
        raise LocalizationError(f"{site.path}: the site bundle has no floor model (the survey "
                                "had no Wi-Fi or BLE rows)")
    if kind != "auto" and kind not in models:
        raise LocalizationError(f"{site.path}: the site bundle has no {kind} floor model (it "
                                f"has {' and '.join(models)}; a BLE floor model is built when "
                                "the survey has BLE on two floors or more)")
    out = _CsvRows(["level", "trace_id", "t_ms", "n_known", "floor", "p_floor", "window_floor",
                    "recorded_floor", "kind"])
    scan_rows: list[dict] = []
    failures = WalkFailures()

    devices, window_ms = device_table(site), ble_window_ms(site)
    # beside floor bundles (a build's OUT), a phone the device table does not know is
    # calibrated online against them, as localize does (SiteMaps.choose)
    floor_maps = SiteMaps.open(site_path) if not is_bundle_dir(site_path) and any(
        d.name != SITE_BUNDLE for d in bundle_dirs(site_path)) else None
    tried_auto = [k for k in ("wifi", "ble") if k in models]
    # auto: Wi-Fi when it classifies a scan, else BLE; BLE first when the Wi-Fi model lacks
    # floors and BLE puts the walk on one of them, as SiteMaps.choose
    lacking = sorted(set(map(str, models["ble"].floors)) - set(map(str, models["wifi"].floors))
                     ) if kind == "auto" and len(tried_auto) == 2 else []

    seen = TraceIds("its rows would be printed under the other's id")

    def one(where: str, trace: Trace) -> None:
        seen.claim(trace.trace_id, where)
        if trace.header.site_id and site.site_id and trace.header.site_id != site.site_id:
            raise LocalizationError(f"{trace.trace_id}: recorded at site "
                                    f"{trace.header.site_id}, but the site bundle {site.path} "
                                    f"is of site {site.site_id}")
        recorded = trace.header.floor_name or ""
        classified: dict[str, tuple] = {}

        def classify(k: str):
            if k not in classified:
                model = models[k]
                scans = _scans(trace, k, window_ms)
                cal = devices.get(trace.header.model or "") if k == "wifi" else None
                if k == "wifi" and cal is None and floor_maps is not None:
                    cal = unknown_phone_calibration(model, [s for s in scans if s is not None],
                                                    floor_maps.floor_bundle)
                    if cal is not None:
                        click.echo(f"{trace.trace_id}: phone {trace.header.model or '?'} not in "
                                   f"the device table; Wi-Fi RSSI calibrated online, "
                                   f"k={cal[0]:.3f}, b={cal[1]:+.1f} dB", err=True)
                rssi = model.scan_matrix(scans, cal)
                lp = model.log_proba(rssi)
                classified[k] = model, scans, rssi, lp, np.isfinite(lp).all(axis=1)
            return classified[k]

        tried = [kind] if kind != "auto" else tried_auto
        if lacking:
            _, _, _, lp_b, ok_b = classify("ble")
            if ok_b.any() and str(models["ble"].floors[np.argmax(lp_b[ok_b].sum(axis=0))]) \
                    in lacking:
                tried = ["ble"]
        for k in tried:
            model, scans, rssi, lp, ok = classify(k)
            if ok.any():
                break
        if not ok.any():
            what = {"wifi": "Wi-Fi scans", "ble": "BLE windows"}
            heard = {k: sum(sc is not None for sc in classify(k)[1]) for k in tried}
            why = "; ".join(f"no {what[k]} in the walk" if not n else
                            f"none of its {n} {what[k]} hears a transmitter the floor model "
                            "knows" for k, n in heard.items())
            raise LocalizationError(f"{trace.trace_id}: {why}; floor unknown")
        n_known = np.isfinite(rssi).sum(axis=1)
        mine = []  # the walk's rows, written once it is through
        for i, scan in enumerate(scans):
            lo = max(0, i - window + 1)
            seq = lp[lo:i + 1][ok[lo:i + 1]]
            floor = str(model.floors[np.argmax(lp[i])]) if ok[i] else ""
            mine.append({"level": "scan", "trace_id": trace.trace_id, "t_ms": scan.t_ms,
                         "n_known": int(n_known[i]), "floor": floor,
                         "p_floor": float(np.exp(lp[i].max())) if ok[i] else "",
                         "window_floor": str(model.floors[np.argmax(seq.sum(axis=0))])
                         if len(seq) else "", "recorded_floor": recorded, "kind": k})
        # as localize decides (a walk half on F1, half on F2 said F1 here and F2 there)
        walk_floor = str(model.floors[walk_floor_index(lp[ok], summed=k == "ble")])
        mine.append({"level": "walk", "trace_id": trace.trace_id, "t_ms": "",
                     "n_known": int(ok.sum()), "floor": walk_floor, "p_floor": "",
                     "window_floor": "", "recorded_floor": recorded, "kind": k})
        out.write(mine)
        scan_rows.extend(r for r in mine if r["level"] == "scan")
        if k == "ble" and kind == "auto":
            why = (f"the Wi-Fi floor model lacks floor {', '.join(lacking)}"
                   if tried == ["ble"] else "no Wi-Fi scan classified")
            click.echo(f"{trace.trace_id}: floor {walk_floor} from {int(ok.sum())} BLE windows "
                       f"({why})", err=True)

    total = each_walk(trace_files(walks, failures), failures, one)
    if scan_rows:
        right = sum(bool(r["recorded_floor"])  # "Level 1" is the floor Level_1
                    and r["floor"] in (r["recorded_floor"], floor_key(r["recorded_floor"]))
                    for r in scan_rows)
        ble = sum(r["kind"] == "ble" for r in scan_rows)
        click.echo(f"{len(scan_rows)} scans" + (f" ({ble} of them BLE windows)" if ble else "")
                   + f"; {100 * right / len(scan_rows):.2f} % on the floor the trace files name",
                   err=True)
    failures.exit_if_any(total)


@click.command("wifi-locate")
@click.argument("bundle_path", metavar="BUNDLE",
                type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.argument("walks", nargs=-1, required=True, type=click.Path())
@click.option("--kind", type=click.Choice(["auto", "wifi", "ble"]), default="auto",
              show_default=True,
              help="auto: Wi-Fi when the bundle locates one of the walk's Wi-Fi scans, else "
                   "BLE over its BLE windows (as localize chooses; BLE fixes are about twice "
                   "as far off); wifi or ble: that kind only.")
@click.option("--calibration", default="auto", show_default=True,
              help="RSSI calibration of the walk's phone: auto (Wi-Fi: the bundle's device "
                   "table for a phone it knows; else online from the walk's first 8 scans when "
                   "3 of them hear enough known transmitters, otherwise none; BLE is always "
                   "calibrated online), none, or K,B (calibrated = K * rssi + B dBm; with "
                   "--kind auto the Wi-Fi scans', a walk located by BLE is calibrated online).")
@click.option("--smoothing", type=click.Choice(["walk", "forward", "none"]), default="walk",
              show_default=True,
              help="walk: match each walk's scans together (earlier and later scans: "
                   "offline, as localize --smooth); forward: earlier scans only, as in real "
                   "time (localize without --smooth); none: every scan on its own.")
def wifi_locate_command(bundle_path: Path, walks: tuple[str, ...], kind: str,
                        calibration: str, smoothing: str) -> None:
    """Wi-Fi (or BLE) position per scan (CSV) from the fingerprints of BUNDLE (a floor bundle
    or a folder of bundles: the walk's floor, else the site floor model, picks one).

    \b
    CSV columns (stdout; one line per walk on stderr):
      trace_id, floor  the walk and the floor bundle used
      t_ms             the scan's time (Unix ms)
      n_known          transmitters of the scan the bundle knows
      x_m, y_m         the position (m, map frame); empty when the scan hears none
      sigma_m          weighted RMS spread of the k neighbours (m, at least 1)
      error_m          distance to the walk's waypoint track (waypoints joined linearly in
                       time) at the scan's time; empty outside its first and last waypoint
      kind             wifi (a Wi-Fi scan) or ble (a BLE window)
    """
    from localize.floors import SiteMaps
    from localize.radio_match import WalkSmoothing
    from localize.walk_radio import bundle_positioner, radio_for_walk
    from survey.step_summaries import ble_scans_of, scans_of, waypoints_of

    given = None
    if calibration not in ("auto", "none"):
        try:
            k, b = (float(v) for v in calibration.split(","))
            given = checked_rssi_calibration(k, b)
        except LocalizationError as err:
            raise click.BadParameter(str(err), param_hint="--calibration") from err
        except ValueError as err:
            raise click.BadParameter(f"must be auto, none or K,B (calibrated = K * rssi + B "
                                     f"dBm); got {calibration!r}",
                                     param_hint="--calibration") from err
    failures = WalkFailures()
    # a mistyped path is said before the bundles load
    files = trace_files(walks, failures)
    maps = SiteMaps.open(bundle_path)
    floors_said, in_build = FloorChoices(), SeenWalks("its radio positions (and any error "
                                                      "measured on them) are")
    out = _CsvRows(["trace_id", "floor", "t_ms", "n_known", "x_m", "y_m", "sigma_m", "error_m",
                    "kind"])
    seen = TraceIds("its rows would be printed under the other's id")

    def one(where: str, trace: Trace) -> None:
        seen.claim(trace.trace_id, where)
        kinds = {"wifi": scans_of(trace), "ble": ble_scans_of(trace, maps.ble_window_ms)}
        if kind != "auto" and not kinds[kind]:
            other = "ble" if kind == "wifi" else "wifi"
            hint = f"; it has {other} scans: --kind {other}" if kinds[other] else ""
            raise LocalizationError(f"{trace.trace_id}: no {kind} scans{hint}")
        if not any(kinds.values()):
            raise LocalizationError(f"{trace.trace_id}: no Wi-Fi scans and no BLE rows")
        h = trace.header  # the floor from the header, else the Wi-Fi, else the BLE floor model
        bundle, how = maps.choose(trace.trace_id, h.site_id or "", h.floor_id or "",
                                  h.floor_name or "", kinds["wifi"], kinds["ble"],
                                  device_model=h.model or "")
        floors_said.say(trace.trace_id, bundle, how)
        if kind != "auto":
            rows, said = locate(trace, bundle, kind, kinds[kind])
        else:  # Wi-Fi when it locates the walk, as localize chooses (walk_radio)
            tried = [] if kinds["wifi"] else ["no wifi scans"]
            for k in (k for k in ("wifi", "ble") if kinds[k]):
                try:
                    rows, said = locate(trace, bundle, k, kinds[k])
                    break
                except LocalizationError as refused:
                    tried.append(str(refused).removeprefix(f"{trace.trace_id}: "))
            else:
                raise LocalizationError(f"{trace.trace_id}: " + "; ".join(tried))
            if k == "ble":
                said += f" (Wi-Fi: {tried[0]})"
        out.write(rows)
        in_build.check(bundle, trace.trace_id)  # a walk that failed is not counted
        click.echo(said, err=True)

    wanted = kind  # --kind: auto, wifi or ble

    def locate(trace: Trace, bundle, kind: str, scans) -> tuple[list[dict], str]:
        """The CSV rows of the walk's ``kind`` scans located on ``bundle``, and its line
        for standard error; a LocalizationError when none is located."""
        pos = bundle_positioner(bundle, kind)
        if pos is None:
            raise LocalizationError(f"{bundle.path}: no {kind} fingerprints in this bundle")
        if calibration == "auto" or given is not None and kind == "ble" and wanted == "auto":
            # a K,B given with --kind auto is the phone's Wi-Fi calibration: its BLE windows
            # are calibrated online, as localize does
            pos, how = radio_for_walk(bundle, trace.header.model, scans, kind=kind)
        elif given is None:
            how = "none"
        else:
            pos, how = pos.with_calibration(*given), f"given k={given[0]:g}, b={given[1]:+g} dB"
        fixes = (pos.locate_scans(scans) if smoothing == "none" else pos.locate_walk(
            scans, WalkSmoothing(direction="both" if smoothing == "walk" else "forward")))
        located = np.isfinite(fixes.xy_m[:, 0])
        floor = bundle.manifest.get("floor_name", "")
        if not located.any():
            why = ("hears a transmitter the {} bundle knows" if not fixes.n_known.any() else
                   "got a position from the {} bundle (the known transmitters' rows too old "
                   "or too weak)").format(floor)
            raise LocalizationError(f"{trace.trace_id}: none of its {len(scans)} {kind} scans "
                                    f"{why}; calibration {how}")
        t = np.array([s.t_ms for s in scans], dtype=np.float64)
        t_wp, xy_wp = waypoints_of(trace)
        truth = np.full((len(scans), 2), np.nan)
        inside = (t >= t_wp[0]) & (t <= t_wp[-1]) if len(t_wp) >= 2 else np.zeros(len(t), bool)
        if inside.any():
            truth[inside, 0] = np.interp(t[inside], t_wp, xy_wp[:, 0])
            truth[inside, 1] = np.interp(t[inside], t_wp, xy_wp[:, 1])
        err = np.hypot(*(fixes.xy_m - truth).T)
        rows = []
        for i, scan in enumerate(scans):
            rows.append({"trace_id": trace.trace_id, "floor": floor, "kind": kind,
                         "t_ms": scan.t_ms, "n_known": int(fixes.n_known[i]),
                         "x_m": float(fixes.xy_m[i, 0]) if np.isfinite(fixes.xy_m[i, 0]) else "",
                         "y_m": float(fixes.xy_m[i, 1]) if np.isfinite(fixes.xy_m[i, 1]) else "",
                         "sigma_m": float(fixes.sigma_m[i]) if np.isfinite(fixes.sigma_m[i])
                         else "", "error_m": float(err[i]) if np.isfinite(err[i]) else ""})
        e = err[np.isfinite(err)]
        return rows, (f"{trace.trace_id}: {len(scans)} {kind} scans on {floor}, "
                      f"{int(located.sum())} located; calibration {how}"
                      + (f"; error vs waypoint track median {np.median(e):.2f} m"
                         if len(e) else ""))

    total = each_walk(files, failures, one)
    in_build.finish()
    failures.exit_if_any(total)
