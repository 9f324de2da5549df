"""Which floor bundle a walk runs on, and the checks that a walk fits a bundle.

A floor bundle answers for one floor. :class:`SiteMaps` holds the floor bundles of a site and
picks one per walk (:meth:`SiteMaps.choose`): by the walk's floor id or floor name (trace
header), else by the site bundle's Wi-Fi floor model over the walk's Wi-Fi scans, else by its
BLE floor model over the walk's BLE windows (a phone that logs BLE only, as an iPhone app),
else the only floor bundle, else it refuses and says what was missing. A floor model is an
object with ``floor_of(scan) -> floor id | None``
(:class:`~localize.floor_classifier.FloorClassifier`, or
:meth:`KnnRadioPositioner.floor_of`).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from localize.bundle import MapBundle
from localize.errors import LocalizationError
from localize.names import floor_key
from localize.steps import RadioScan, StepSummaries

__all__ = ["FloorModel", "SiteMaps", "check_walk_fits", "unknown_phone_calibration"]


class FloorModel(Protocol):
    def floor_of(self, scan: RadioScan) -> str | None:
        """Floor id of a scan, or None when unsure."""


def check_walk_fits(bundle: MapBundle, steps: StepSummaries) -> None:
    """Refuse walks that cannot be localized on ``bundle``.

    Raises
    ------
    LocalizationError
        No steps; no magnetometer values (unless the caller runs a method without magnetic
        update, see ``require_magnetometer`` of :meth:`Localizer.run`); the walk's site or
        floor id differs from the bundle's.
    """
    where = steps.trace_id or "walk"
    if len(steps) == 0:
        raise LocalizationError(f"{where}: no steps detected, nothing to localize")
    if steps.site_id and bundle.site_id and steps.site_id != bundle.site_id:
        raise LocalizationError(f"{where}: recorded at site {steps.site_id}, but the bundle "
                                f"{bundle.path} is of site {bundle.site_id}")
    if steps.floor_id and bundle.floor_id and steps.floor_id != bundle.floor_id:
        name = f" ({steps.floor_name})" if steps.floor_name else ""
        raise LocalizationError(f"{where}: recorded on floor {steps.floor_id}{name}, but the "
                                f"bundle {bundle.path} is floor {bundle.floor_id} "
                                f"({bundle.manifest.get('floor_name', '')})")


class SiteMaps:
    """The floor bundles of one site.

    Parameters
    ----------
    bundles : iterable of MapBundle
        Floor bundles of one site (distinct floor ids).
    floor_model : FloorModel, optional
        Used over the walk's Wi-Fi scans when the walk carries no floor id.
    ble_floor_model : FloorModel, optional
        Used over the walk's BLE windows when the walk carries no floor id and
        ``floor_model`` classifies none of its Wi-Fi scans.
    site_bundle : str, optional
        What the models came from, for messages (:meth:`open` sets it; "" = none given).
    devices : dict, optional
        Phone model -> ``(k, b)``: the device table the Wi-Fi floor model's training RSSI was
        mapped through (``calibrated = k * rssi + b``, dBm); a walk of a listed phone is
        mapped the same way before its Wi-Fi scans are classified (:meth:`open` reads it
        from the site bundle's ``devices`` table).
    """

    def __init__(self, bundles: Iterable[MapBundle], floor_model: FloorModel | None = None,
                 ble_floor_model: FloorModel | None = None, site_bundle: str = "",
                 devices: dict[str, tuple[float, float]] | None = None):
        self.bundles: dict[str, MapBundle] = {}
        sites = set()
        for b in bundles:
            if b.grid is None:
                continue  # a site-level bundle: holds the floor models, no rasters
            if b.floor_id in self.bundles:
                raise LocalizationError(f"two bundles for floor {b.floor_id}: "
                                        f"{self.bundles[b.floor_id].path} and {b.path}")
            self.bundles[b.floor_id] = b
            sites.add(b.site_id)
        if len(sites) > 1:
            raise LocalizationError(f"bundles of several sites given: {sorted(sites)}")
        if not self.bundles:
            raise LocalizationError("no floor bundle given")
        self.site_id = sites.pop()
        self.floor_model = floor_model
        self.ble_floor_model = ble_floor_model
        self.site_bundle = site_bundle
        self.devices = dict(devices or {})
        self._by_name = {b.manifest.get("floor_name", ""): b for b in self.bundles.values()}

    def __repr__(self) -> str:
        floors = ", ".join(b.manifest.get("floor_name") or f for f, b in self.bundles.items())
        models = ", ".join(name for name, m in (("Wi-Fi", self.floor_model),
                                                ("BLE", self.ble_floor_model)) if m is not None)
        return (f"SiteMaps(site {self.site_id!r}, floors {floors}, floor models "
                f"{models or 'none'}{f' from {self.site_bundle}' if self.site_bundle else ''})")

    def floor_bundle(self, floor: str) -> MapBundle | None:
        """The bundle of a floor named as the floor models name them (the floor name the
        survey recorded, else the floor id); None when there is none."""
        return self._by_name.get(floor) or self.bundles.get(floor)

    def _named(self, floor_name: str) -> MapBundle | None:
        """The bundle of the floor a walk names, by name or by the name's store key (a
        walk of ``Level 1`` was built into the bundle of ``Level_1``)."""
        return self._by_name.get(floor_name) or self._by_name.get(floor_key(floor_name))

    @property
    def ble_window_ms(self) -> int:
        """Length (ms) of the BLE windows the floor bundles' BLE fingerprints (and the site's
        BLE floor model) were built from: what a walk's BLE rows must be grouped into
        (:func:`survey.step_summaries.ble_scans_of`)."""
        return ble_window_ms(next(iter(self.bundles.values())))

    @classmethod
    def open(cls, path: str | Path) -> SiteMaps:
        """The floor bundles at ``path``: one floor bundle, a folder of bundles (as
        ``indoormap build`` writes, with the site bundle ``_site`` whose floor models then
        pick the floor of walks that name none: Wi-Fi, else BLE when the site bundle has a
        BLE floor model), or a registry's site or floor folder (``REG/<site>``,
        ``REG/<site>/<floor>``: their current versions).

        Raises
        ------
        LocalizationError
            Nothing there is a bundle; bundles of several sites or two of one floor.
        BundleError, RegistryError
            A damaged bundle or registry pointer (:func:`~localize.bundle.load_bundle`).
        """
        from localize.bundle import bundle_dirs, is_bundle_dir, is_registry_floor_dir, load_bundle
        from localize.floor_classifier import site_floor_models

        path = Path(path)
        # a registry floor with no current version: load_bundle says so and what to do
        subs = [load_bundle(path)] if is_bundle_dir(path) or is_registry_floor_dir(path) \
            else [load_bundle(p) for p in bundle_dirs(path)]
        if not subs:
            if not path.exists():
                raise LocalizationError(f"{path}: no such file or folder")
            raise LocalizationError(f"{path}: neither a bundle nor a folder of bundles (nor a "
                                    "registry's site folder)")
        site = [b for b in subs if b.manifest.get("kind") == "site"]
        floors = [b for b in subs if b.manifest.get("kind") != "site"]
        if not floors:
            raise LocalizationError(f"{path}: a site bundle only (floor model, device table); "
                                    "localizing needs floor bundles: give the folder "
                                    "`indoormap build` wrote, or one floor's bundle")
        models = site_floor_models(site[0]) if site else {}
        try:
            return cls(floors, floor_model=models.get("wifi"),
                       ble_floor_model=models.get("ble"),
                       site_bundle=str(site[0].path) if site else "",
                       devices=device_table(site[0]) if site else None)
        except LocalizationError as err:
            raise LocalizationError(f"{path}: {err}") from err

    def select(self, steps: StepSummaries,
               ble_scans: Sequence[RadioScan | None] | None = None, *,
               device_model: str = "") -> MapBundle:
        """The bundle of the walk's floor (see :meth:`choose`); ``ble_scans`` are the walk's
        BLE windows (:func:`survey.step_summaries.ble_scans_of`), the steps carry its Wi-Fi
        scans."""
        return self.choose(steps.trace_id, steps.site_id, steps.floor_id, steps.floor_name,
                           steps.scans, ble_scans, device_model=device_model)[0]

    def select_for(self, trace_id: str, site_id: str, floor_id: str, floor_name: str,
                   wifi_scans: Sequence[RadioScan | None] | None,
                   ble_scans: Sequence[RadioScan | None] | None = None, *,
                   device_model: str = "") -> MapBundle:
        """The bundle of a walk's floor (see :meth:`choose`)."""
        return self.choose(trace_id, site_id, floor_id, floor_name, wifi_scans, ble_scans,
                           device_model=device_model)[0]

    def _wifi_calibration(self, heard: Sequence[RadioScan], device_model: str
                          ) -> tuple[tuple[float, float] | None, bool]:
        """The ``(k, b)`` mapping a phone's Wi-Fi RSSI onto the floor model's scale: the
        device table's entry, else one calibrated online from the walk's scans ``heard``
        (:func:`unknown_phone_calibration`; None when it cannot be), and whether it was."""
        known = self.devices.get(device_model)
        if known is not None:
            return known, False
        online = unknown_phone_calibration(self.floor_model, heard, self.floor_bundle)
        return online, online is not None

    def _knows(self, model, bundle: MapBundle) -> bool:
        """Whether a floor model has ``bundle``'s floor among its classes (a model that does
        not list its floors is taken to know them all)."""
        known = getattr(model, "floors", None)
        return known is None or any(
            (b := self.floor_bundle(str(f))) is not None and b.floor_id == bundle.floor_id
            for f in known)

    def _lacking(self, model) -> list[str]:
        """The given floors (by name) a floor model cannot put a walk on: none when it does
        not list its floors."""
        return [n for n, b in sorted(self._by_name.items()) if not self._knows(model, b)]

    def _wifi_doubt(self, header_bundle: MapBundle,
                    wifi_scans: Sequence[RadioScan | None] | None, device_model: str) -> str:
        """``"; but the Wi-Fi floor model puts V of N Wi-Fi scans on floor F"`` when it puts
        :data:`DOUBT_SHARE` or more of :data:`DOUBT_MIN_SCANS` or more of the walk's scans on
        a floor other than the header's (``header_bundle``), else ``""``: the header decides,
        but a walk recorded under the wrong floor name is said. A model that lacks the
        header's floor (Wi-Fi surveyed on other floors only) puts every walk on a floor it
        knows and so has no say."""
        model = self.floor_model
        heard = [s for s in (wifi_scans or ()) if s is not None]
        if model is None or len(heard) < DOUBT_MIN_SCANS or not self._knows(
                model, header_bundle):
            return ""
        calibration, _ = self._wifi_calibration(heard, device_model)
        classified = _classified(model, heard, calibration)
        best, n_on, n_known = _walk_floor(model, heard, summed=False, classified=classified)
        other = self.floor_bundle(best) if best is not None else None
        change = _floor_change(model, classified)
        if (other is None or other.floor_id == header_bundle.floor_id
                or n_known < DOUBT_MIN_SCANS or n_on < DOUBT_SHARE * n_known):
            return change
        return f"{HEADER_DOUBT} {n_on} of {n_known} Wi-Fi scans on floor {best}" + change

    def choose(self, trace_id: str, site_id: str, floor_id: str, floor_name: str,
               wifi_scans: Sequence[RadioScan | None] | None,
               ble_scans: Sequence[RadioScan | None] | None = None, *,
               device_model: str = "") -> tuple[MapBundle, str]:
        """The bundle of a walk's floor and how it was chosen (a phrase for logs).

        In order: the floor id, else the floor name the trace header gives (empty strings
        when it says nothing); else the floor most of the walk's Wi-Fi scans are put on by
        :attr:`floor_model`; else the most likely floor of the walk's BLE windows
        (``ble_scans``) together under :attr:`ble_floor_model` (their log-probabilities
        summed; a model without ``log_proba``: the floor most windows are put on); else the
        only floor bundle. Wi-Fi decides whenever it classifies a scan of the walk, even when
        BLE would say another floor: on the real site1 walks (10-fold by walk) Wi-Fi puts
        every walk on its floor, BLE 98.3 % (``docs/radio.md``). Except a Wi-Fi model of one
        model that lacks some of the site's floors (Wi-Fi surveyed on only some of them),
        which puts every walk on a floor it knows: when the BLE model names a floor the
        Wi-Fi model lacks, BLE decides; otherwise (BLE names a floor Wi-Fi knows, or cannot
        tell) Wi-Fi does. A walk's Wi-Fi RSSI is first mapped through :attr:`devices`'s
        entry for ``device_model`` (its phone model), as the model's training RSSI was;
        another phone's is calibrated online first (:func:`unknown_phone_calibration`).

        Returns
        -------
        (MapBundle, str)
            How: ``"floor id in the trace header"``, ``"floor name in the trace header"``
            (each with :meth:`_wifi_doubt`'s note when the Wi-Fi floor model disagrees),
            ``"Wi-Fi floor model (V of N Wi-Fi scans on it)"`` (with ``"; RSSI calibrated
            online, k=K, b=B dB"`` for an unknown phone), ``"BLE floor model (V of N BLE
            windows on it; no Wi-Fi scans in the walk)"`` (N: the scans that hear a
            transmitter the model knows, V: those put on the chosen floor alone) or ``"the
            only floor bundle"``.

        Raises
        ------
        LocalizationError
            Another site, a floor without a bundle, or no way to tell the floor: the message
            says, per floor model, what was missing (the model, the walk's scans, or a scan
            hearing a transmitter the model knows).
        """
        where = trace_id or "walk"
        if site_id and site_id != self.site_id:
            raise LocalizationError(f"{where}: recorded at site {site_id}, the bundles "
                                    f"are of site {self.site_id}")
        if floor_id:
            if floor_id in self.bundles:
                found = self.bundles[floor_id]
                return found, "floor id in the trace header" + self._wifi_doubt(
                    found, wifi_scans, device_model)
            given = ", ".join(sorted(self._by_name))
            raise LocalizationError(
                f"{where}: unknown floor {floor_id} ({floor_name or '?'}); " + (
                    f"the bundles given hold only floor {given}: give the folder of the site's "
                    "bundles (what `indoormap build` writes) to localize walks of every floor"
                    if len(self._by_name) == 1 else f"bundles exist for floors {given}"))
        if floor_name and (found := self._named(floor_name)):
            return found, "floor name in the trace header" + self._wifi_doubt(
                found, wifi_scans, device_model)
        missing = []
        deferred = None  # a Wi-Fi model lacking floors: BLE may name one of those first
        for name, what, model, scans in (
                ("Wi-Fi", "Wi-Fi scans", self.floor_model, wifi_scans),
                ("BLE", "BLE windows", self.ble_floor_model, ble_scans)):
            heard = [s for s in (scans or ()) if s is not None]
            if model is None:
                missing.append(f"no {name} floor model" + (
                    " (no site bundle given)" if not self.site_bundle else
                    f" in the site bundle {self.site_bundle}" + (
                        " (built before indoormap made BLE floor models, or from a survey "
                        "with BLE on fewer than two floors)" if name == "BLE" else "")))
                continue
            if not heard:
                missing.append(f"no {what} in the walk")
                continue
            calibration, online = (self._wifi_calibration(heard, device_model)
                                   if name == "Wi-Fi" else (None, False))
            calibrated = (f"; RSSI calibrated online, k={calibration[0]:.3f}, "
                          f"b={calibration[1]:+.1f} dB") if online else ""
            classified = _classified(model, heard, calibration)
            best, n_on, n_known = _walk_floor(model, heard, summed=name == "BLE",
                                              classified=classified)
            if best is None:
                missing.append(f"none of its {len(heard)} {what} hears a transmitter the "
                               f"{name} floor model knows")
                continue
            # the models' floors are the floor names the survey recorded (or ids)
            found = self.floor_bundle(best)
            if found is None:
                raise LocalizationError(f"{where}: the {name} floor model says floor {best}, "
                                        "which has no bundle")
            how = f"{name} floor model ({n_on} of {n_known} {what} on it{calibrated})" + (
                _floor_change(model, classified) if name == "Wi-Fi" else "")
            lacking = self._lacking(model)
            if name == "Wi-Fi" and lacking and self.ble_floor_model is not None:
                # it puts a walk on a floor it knows even when the walk is on one it lacks:
                # the BLE model may name one of those
                deferred = found, how, lacking
                continue
            tail = _also(missing)
            if deferred is not None:
                wifi_found, wifi_how, wifi_lacking = deferred
                note = f"; the Wi-Fi floor model lacks floor {', '.join(wifi_lacking)}"
                if best in wifi_lacking:  # BLE names a floor the Wi-Fi model lacks: it decides
                    return found, how + _lacks(lacking) + note + tail
                # BLE names a floor the Wi-Fi model knows: Wi-Fi, the better, decides; the BLE
                # model confirms it only if it could have named the floors Wi-Fi lacks
                unseen = [f for f in wifi_lacking if f in lacking]
                return wifi_found, wifi_how + (_lacks(unseen) if unseen else note) + tail
            return found, how + _lacks(lacking) + tail
        if deferred is not None:  # BLE could not tell: the Wi-Fi model decides, unchecked
            return deferred[0], deferred[1] + _lacks(deferred[2]) + _also(missing)
        if len(self.bundles) == 1:
            return next(iter(self.bundles.values())), "the only floor bundle"
        floors = ", ".join(sorted(self._by_name))
        raise LocalizationError(f"{where}: the walk names no floor (no floor id or known floor "
                                f"name in its header) and no floor model decided: "
                                f"{'; '.join(missing)}; floors: {floors} (give its floor's "
                                "bundle, or its floor as a walk plan's floor_name)")


#: A header's floor is doubted (:meth:`SiteMaps.choose`) when the Wi-Fi floor model puts at
#: least this share of at least :data:`DOUBT_MIN_SCANS` of the walk's scans on another floor
#: (on the site1 walks it puts 99.96 % of the scans on their own floor, `docs/radio.md`).
DOUBT_SHARE = 0.8
DOUBT_MIN_SCANS = 5
#: How :meth:`SiteMaps.choose`'s phrase for a header's floor goes on when the Wi-Fi floor
#: model doubts it (what a caller looks for to warn).
HEADER_DOUBT = "; but the Wi-Fi floor model puts"

#: How :meth:`SiteMaps.choose`'s phrase goes on when the walk's Wi-Fi scans change floor
#: (:func:`_floor_change`; a warning).
FLOOR_CHANGE = "; its Wi-Fi scans change floor"
#: A change of floor is said when each part has this many scans, the floor model puts this
#: share of all scans on their part's floor, and the two parts explain this many scans more
#: than one floor does.
CHANGE_MIN_SCANS, CHANGE_SHARE, CHANGE_GAIN_SCANS = 5, 0.8, 5


def _classified(model: FloorModel, scans: Sequence[RadioScan],
                calibration: tuple[float, float] | None
                ) -> tuple[NDArray[np.float64], list[RadioScan]] | None:
    """The log-probabilities (k, floors) of the ``scans`` a model with ``scan_matrix`` and
    ``log_proba`` classifies (those hearing a transmitter it knows; their RSSI first mapped
    through ``calibration`` ``(k, b)``), and those scans; None for another model."""
    if not (hasattr(model, "log_proba") and hasattr(model, "scan_matrix")):
        return None
    lp = np.asarray(model.log_proba(model.scan_matrix(scans, calibration)), dtype=np.float64)
    ok = np.isfinite(lp).all(axis=1)
    return lp[ok], [scan for scan, good in zip(scans, ok) if good]


def _floor_change(model: FloorModel,
                  classified: tuple[NDArray[np.float64], list[RadioScan]] | None) -> str:
    """``"; its Wi-Fi scans change floor, F1 to F2 at scan 18 of 37 (t ... ms): ..."`` when
    the floor model's floor per scan (:func:`_classified`) splits the walk (in time order)
    into two parts on two floors (:data:`CHANGE_MIN_SCANS`, :data:`CHANGE_SHARE`,
    :data:`CHANGE_GAIN_SCANS`): a lift or stairs mid-walk, whose other part is localized on
    the wrong floor; else ``""`` (and for a model without ``log_proba``)."""
    if classified is None:
        return ""
    lp, kept = classified
    each = np.argmax(lp, axis=1)
    n, m = len(each), lp.shape[1]
    if n < 2 * CHANGE_MIN_SCANS:
        return ""
    one_hot = np.eye(m, dtype=np.int64)[each]
    before = np.cumsum(one_hot, axis=0)  # scans on each floor among the first i + 1
    split = np.arange(CHANGE_MIN_SCANS, n - CHANGE_MIN_SCANS + 1)  # first scan of part two
    head, tail = before[split - 1], before[-1] - before[split - 1]
    a, b = head.argmax(axis=1), tail.argmax(axis=1)
    agree = np.where(a != b, head.max(axis=1) + tail.max(axis=1), 0)
    k = int(np.argmax(agree))
    if agree[k] < CHANGE_SHARE * n or agree[k] < before[-1].max() + CHANGE_GAIN_SCANS:
        return ""
    at = split[k]
    t_ms = kept[at].t_ms
    return (f"{FLOOR_CHANGE}, {model.floors[a[k]]} to {model.floors[b[k]]} at scan {at + 1} of "
            f"{n} ({t_ms:.0f} ms): a walk is localized on one floor, so one part of it is on the "
            "wrong one (localize the parts apart)")


#: How :meth:`SiteMaps.choose`'s phrase goes on when the floor model that chose lacks some of
#: the floors given (Wi-Fi surveyed on only some of them, or a folder whose site bundle was
#: rebuilt from fewer floors than its floor bundles): a warning, as a walk on those floors is
#: put on another.
MODEL_LACKS = "; the model lacks floor"
#: :data:`MODEL_LACKS`'s whole phrase; group 1 the floors lacking ("F2, F3")
LACKS_PHRASE = re.compile(re.escape(MODEL_LACKS) + r" (.+?): walks there are put on a floor "
                          r"it knows")


def _lacks(floors: Sequence[str]) -> str:
    """:data:`MODEL_LACKS`'s phrase for ``floors`` the deciding model cannot name ("" for
    none)."""
    return (f"{MODEL_LACKS} {', '.join(floors)}: walks there are put on a floor it knows"
            if floors else "")


def _also(missing: Sequence[str]) -> str:
    """``"; A, B"``: what the models that did not decide lacked ("" for nothing)."""
    return f"; {', '.join(missing)}" if missing else ""


#: BLE window (ms) of bundles whose manifest does not record one (they were all built with it)
DEFAULT_BLE_WINDOW_MS = 2000


def ble_window_ms(bundle: MapBundle) -> int:
    """The BLE window (ms) a bundle was built with (its manifest's
    ``build.params.radio.ble_window_ms``, a site bundle's ``build.radio_params.ble_window_ms``;
    :data:`DEFAULT_BLE_WINDOW_MS` when it does not say).

    Raises
    ------
    LocalizationError
        A recorded value that is not a whole number of ms between 100 and 600,000.
    """
    build = bundle.manifest.get("build") or {}
    radio = build.get("radio_params") or (build.get("params") or {}).get("radio") or {}
    value = radio.get("ble_window_ms", DEFAULT_BLE_WINDOW_MS) if isinstance(radio, dict) \
        else DEFAULT_BLE_WINDOW_MS
    if isinstance(value, bool) or not isinstance(value, int) or not 100 <= value <= 600_000:
        raise LocalizationError(f"{bundle.path}: build.params.radio.ble_window_ms is "
                                f"{value!r}, not a window length in ms (100-600000)")
    return value


def walk_floor_index(log_proba: np.ndarray, *, summed: bool) -> int:
    """The floor (column) of a walk from its classified scans' log-probabilities (k, floors),
    in time order: with ``summed`` the largest summed log-probability (BLE windows), else
    the floor most scans are put on, ties to the one met first in the walk (Wi-Fi scans).
    What :meth:`SiteMaps.choose` and ``indoormap floor``'s walk row both decide by."""
    if summed:
        return int(np.argmax(log_proba.sum(axis=0)))
    each = np.argmax(log_proba, axis=1)
    counts = np.bincount(each, minlength=log_proba.shape[1])
    tied = np.flatnonzero(counts == counts.max())
    return int(each[np.isin(each, tied)][0])


def unknown_phone_calibration(model: FloorModel, scans: Sequence[RadioScan],
                              floor_bundle: Callable[[str], MapBundle | None]
                              ) -> tuple[float, float] | None:
    """``(k, b)`` mapping the Wi-Fi RSSI of a phone the device table does not know onto the
    survey's scale (``calibrated = k * rssi + b``, dBm), for the Wi-Fi floor model: estimated
    from its first scans against the Wi-Fi fingerprints of the floor ``model`` puts its raw
    scans on (``floor_bundle(floor)`` gives that floor's bundle), as
    :func:`localize.walk_radio.radio_for_walk` calibrates it for positioning. None when no
    raw scan is classified, the floor has no bundle or no Wi-Fi fingerprints, or too few
    scans hear its transmitters.

    On site1 with RSSI 12 dB low (``benchmarks/wifi_accuracy.py --folds 10``), the floor
    model puts 98.50 % of the held-out scans on their floor as they read, 99.92 % so
    calibrated (99.96 % at the survey phone's own scale)."""
    from localize.walk_radio import (MIN_CALIBRATION_SCANS, ONLINE_CALIBRATION_SCANS,
                                     bundle_positioner)

    raw_floor = _walk_floor(model, scans, summed=False)[0]
    bundle = floor_bundle(raw_floor) if raw_floor is not None else None
    pos = bundle_positioner(bundle, "wifi") if bundle is not None else None
    if pos is None:
        return None
    cal = pos.online_calibration(list(scans[:ONLINE_CALIBRATION_SCANS]))
    return (cal.k, cal.b) if cal.n_scans >= MIN_CALIBRATION_SCANS else None


def _walk_floor(model: FloorModel, scans: Sequence[RadioScan], *, summed: bool,
                calibration: tuple[float, float] | None = None,
                classified: tuple[NDArray[np.float64], list[RadioScan]] | None = None
                ) -> tuple[str | None, int, int]:
    """The floor of a walk's scans under a floor model, the number of scans put on it alone
    and the number of scans it classifies (those hearing a transmitter it knows).

    With a model that has ``scan_matrix`` and ``log_proba``
    (:class:`~localize.floor_classifier.FloorClassifier`), its RSSI first mapped through
    ``calibration`` ``(k, b)`` when given: with ``summed`` the floor of the largest summed
    log-probability (as :meth:`mapping.floor_model.FloorModel.predict_walks`), else the floor
    most scans are put on (ties: the first of them in the walk). None when no scan is
    classified. ``classified``: :func:`_classified` of these scans, when already made."""
    classified = classified or _classified(model, scans, calibration)
    if classified is not None:
        lp = classified[0]
        if not len(lp):
            return None, 0, 0
        best = walk_floor_index(lp, summed=summed)
        return str(model.floors[best]), int((np.argmax(lp, axis=1) == best).sum()), len(lp)
    votes: dict[str, int] = {}
    for scan in scans:
        f = model.floor_of(scan)
        if f is not None:
            votes[f] = votes.get(f, 0) + 1
    if not votes:
        return None, 0, 0
    best_floor = max(votes, key=votes.get)
    return best_floor, votes[best_floor], sum(votes.values())


def device_table(bundle: MapBundle) -> dict[str, tuple[float, float]]:
    """Phone model -> ``(k, b)`` of a bundle's ``devices`` table (the Wi-Fi RSSI maps
    ``calibrated = k * rssi + b`` the build fitted); empty without one.

    Raises
    ------
    LocalizationError
        A table without the ``device_model``, ``k`` and ``b`` columns, or with a ``k`` or
        ``b`` that is not a finite number. The limits of
        :func:`~localize.rssi_calibration.checked_rssi_calibration` (for calibrations a user
        gives) are not applied: the build mapped its training RSSI through whatever it
        fitted, and one unusual phone must not refuse the site for every walk.
    """
    if not bundle.has_table("devices"):
        return {}
    table = bundle.table("devices")
    missing = [c for c in ("device_model", "k", "b") if c not in table.column_names]
    if missing:
        raise LocalizationError(f"{bundle.path}: table 'devices' lacks columns {missing}")
    out = {}
    for model, k, b in zip(table.column("device_model").to_pylist(),
                           table.column("k").to_pylist(), table.column("b").to_pylist()):
        try:
            kb = (float(k), float(b))
            if not np.isfinite(kb).all() or kb[0] <= 0:
                raise ValueError(f"k = {k}, b = {b} is not a calibration (k > 0, finite)")
        except (TypeError, ValueError) as err:
            raise LocalizationError(f"{bundle.path}: table 'devices', phone {model!r}: "
                                    f"{err}") from err
        out[str(model)] = kb
    return out
