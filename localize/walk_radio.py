"""The radio model a walk is localized with: the bundle's fingerprints, calibrated for the
walk's phone.

A phone model in the bundle's device table (fitted on Wi-Fi) uses its stored RSSI map
``calibrated = k * rssi + b``; any other phone, and BLE, is calibrated online from the walk's
first :data:`ONLINE_CALIBRATION_SCANS` scans (a search for the ``(k, b)`` most consistent with
the map, no positions needed) when at least :data:`MIN_CALIBRATION_SCANS` of them hear enough
known transmitters, else left uncalibrated. BLE is fitted an offset alone, applied only when
it exceeds :data:`BLE_MIN_OFFSET_DB`. Positioners are cached per bundle id: bundles are
content-addressed, so the cache cannot go stale, and a folder of walks builds each bundle's
positioner once.

Which fingerprints a walk uses (:func:`walk_radio`): Wi-Fi whenever one of its Wi-Fi scans is
located, else BLE when the bundle has BLE fingerprints and a BLE window of the walk is located
(BLE fixes are about twice as far off: 6.7 m median on the real site1 traces against 3.6 m
for Wi-Fi, ``docs/radio.md``), else Wi-Fi again (the walk then has no fix).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from localize.bundle import MapBundle
from localize.filter import first_radio_fix
from localize.fingerprint_positioner import FingerprintPositioner
from localize.steps import RadioScan, StepSummaries

__all__ = ["BLE_MIN_OFFSET_DB", "MIN_CALIBRATION_SCANS", "ONLINE_CALIBRATION_SCANS",
           "WalkRadio", "bundle_positioner", "radio_for_walk", "walk_radio"]

#: Scans of a walk used to calibrate an unknown phone's RSSI online.
ONLINE_CALIBRATION_SCANS = 8
#: Fewer usable scans than this leave the phone uncalibrated: from one BLE window the search
#: found k = 1.7, b = +74 dB and tripled the walk's error (6.79 m against 2.14 m uncalibrated).
MIN_CALIBRATION_SCANS = 3
#: BLE is calibrated by an offset alone (``k = 1``), and only when the offset found is larger
#: than this (dB). A walk's few 2 s BLE windows hear a handful of beacons over a narrow RSSI
#: range: on the survey phones' own site1 walks the slope-and-offset search found slopes from
#: 0.5 to 1.42 (10th-90th percentile) and the offset alone spreads by about 3.4 dB around 0,
#: so calibrating every walk made the survey phones' fixes worse (7.17 m median against
#: 6.68 m uncalibrated), while a phone 12 dB low needs it (10.76 m uncalibrated).
BLE_MIN_OFFSET_DB = 4.0

_CACHE_SIZE = 16
_POSITIONERS: dict[tuple[str, str], FingerprintPositioner | None] = {}


def bundle_positioner(bundle: MapBundle, kind: str) -> FingerprintPositioner | None:
    """The bundle's ``kind`` (``"wifi"`` or ``"ble"``) fingerprint positioner, uncalibrated;
    None when the bundle has no such fingerprints. Built once per bundle id."""
    key = (bundle.bundle_id, kind)
    if key not in _POSITIONERS:
        if len(_POSITIONERS) >= _CACHE_SIZE:
            _POSITIONERS.clear()
        _POSITIONERS[key] = FingerprintPositioner.from_bundle(bundle, kind)
    return _POSITIONERS[key]


def radio_for_walk(bundle: MapBundle, device_model: str | None,
                   scans: Sequence[RadioScan | None] | None, *, kind: str | None = None
                   ) -> tuple[FingerprintPositioner | None, str]:
    """The bundle's Wi-Fi (else BLE, or ``kind``) positioner calibrated for the walk's phone,
    and how it was calibrated (a sentence for logs). The default kind follows the bundle
    only; :func:`walk_radio` also looks at the walk's scans (BLE for a walk without Wi-Fi).

    Parameters
    ----------
    bundle : MapBundle
        A floor bundle with fingerprint tables.
    device_model : str or None
        The phone model of the walk (trace header), looked up in the bundle's device table.
    scans : sequence of RadioScan (None entries skipped), optional
        The walk's scans, of the same kind; the first :data:`ONLINE_CALIBRATION_SCANS`
        calibrate a phone the table does not know.
    kind : {"wifi", "ble"}, optional
        Fingerprints to use (default: Wi-Fi when the bundle has them, else BLE).

    Returns
    -------
    (positioner or None, str)
        ``(None, "")`` when the bundle has no fingerprints of that kind.
    """
    pos, kind = next(((p, k) for k in ([kind] if kind else ["wifi", "ble"])
                      if (p := bundle_positioner(bundle, k)) is not None), (None, ""))
    if pos is None:
        return None, ""
    known = pos.for_device(bundle, device_model or "") if kind == "wifi" else None
    if known is not None:
        return known, f"device table ({device_model}: k={known.rssi_k:.3f}, " \
                      f"b={known.rssi_b:+.1f} dB)"
    first = [s for s in (scans or []) if s is not None][:ONLINE_CALIBRATION_SCANS]
    if not first:
        return pos, "uncalibrated (no scan to calibrate from)"
    ble = kind == "ble"
    cal = pos.online_calibration(first, k_range=(1.0, 1.0)) if ble else \
        pos.online_calibration(first)
    if cal.n_scans < MIN_CALIBRATION_SCANS:
        return pos, (f"uncalibrated ({cal.n_scans} of the first {len(first)} scans hear enough "
                     f"known transmitters to calibrate from; {MIN_CALIBRATION_SCANS} needed)")
    if ble and abs(cal.b) <= BLE_MIN_OFFSET_DB:
        return pos, (f"uncalibrated (the BLE offset found online from {cal.n_scans} scans, "
                     f"{cal.b:+.1f} dB, is within {BLE_MIN_OFFSET_DB:g} dB)")
    return pos.with_calibration(cal.k, cal.b), \
        f"online from {cal.n_scans} scans ({'offset only, ' if ble else f'k={cal.k:.3f}, '}" \
        f"b={cal.b:+.1f} dB)"


@dataclass(frozen=True)
class WalkRadio:
    """The radio a walk is localized with (:func:`walk_radio`).

    Attributes
    ----------
    steps : StepSummaries
        The walk, its steps carrying the scans of ``kind`` (BLE windows in place of the Wi-Fi
        scans when BLE was chosen).
    radio : FingerprintPositioner or None
        The bundle's positioner of that kind, calibrated for the walk's phone; None when the
        bundle has no fingerprints.
    kind : {"wifi", "ble", ""}
        The fingerprints used ("" without any).
    calibration : str
        How the phone was calibrated (a sentence for logs).
    reason : str
        Why BLE was used instead of Wi-Fi ("no Wi-Fi scans in the walk", ...); "" for Wi-Fi.
    fix_name : str
        The fixes in messages (:func:`localize.start.start_position`'s ``radio_name``):
        ``"Wi-Fi"`` or ``"BLE"`` when a scan of the walk is located, else what was tried
        (``"Wi-Fi or BLE"``, ...); "" without fingerprints.
    """

    steps: StepSummaries
    radio: FingerprintPositioner | None
    kind: str
    calibration: str
    reason: str = ""
    fix_name: str = ""


def walk_radio(bundle: MapBundle, device_model: str | None, steps: StepSummaries,
               ble_scans: Sequence[RadioScan] = ()) -> WalkRadio:
    """The radio model of a walk: the bundle's Wi-Fi fingerprints when one of the walk's Wi-Fi
    scans can be located, else its BLE fingerprints when one of the walk's BLE windows can,
    else Wi-Fi (or BLE when the bundle has no Wi-Fi fingerprints) with no fix.

    Wi-Fi comes first whenever it locates the walk: BLE fixes are about twice as far off
    (6.7 m median against 3.6 m on the real site1 traces, ``docs/radio.md``).

    Parameters
    ----------
    bundle : MapBundle
        The walk's floor bundle.
    device_model : str or None
        The walk's phone model (trace header).
    steps : StepSummaries
        The walk, its steps carrying its Wi-Fi scans.
    ble_scans : sequence of RadioScan
        The walk's BLE windows, keyed like the bundle's BLE fingerprints
        (:func:`survey.step_summaries.ble_scans_of`); empty: Wi-Fi only.

    Returns
    -------
    WalkRadio
        The steps with the chosen kind's scans attached, the calibrated positioner, and why.

    Examples
    --------
    >>> wr = walk_radio(bundle, trace.header.model, step_summaries(trace),
    ...                 ble_scans_of(trace))                                # doctest: +SKIP
    >>> wr.kind, wr.reason                                                  # doctest: +SKIP
    ('ble', 'no Wi-Fi scans in the walk')
    >>> track = Localizer(bundle, radio=wr.radio).run(wr.steps)             # doctest: +SKIP
    """
    has_wifi = bundle_positioner(bundle, "wifi") is not None
    has_ble = bundle_positioner(bundle, "ble") is not None
    wifi = None
    if has_wifi:
        pos, how = radio_for_walk(bundle, device_model, steps.scans, kind="wifi")
        if first_radio_fix(pos, steps) is not None:
            return WalkRadio(steps, pos, "wifi", how, fix_name="Wi-Fi")
        wifi = WalkRadio(steps, pos, "wifi", how, fix_name="Wi-Fi or BLE" if has_ble else
                         "Wi-Fi")
    if not has_ble:
        return wifi if wifi is not None else WalkRadio(steps, None, "", "")
    ble_steps = steps.with_scans(ble_scans)
    pos, how = radio_for_walk(bundle, device_model, ble_scans, kind="ble")
    located = first_radio_fix(pos, ble_steps) is not None
    if wifi is not None and not located:
        return wifi  # nothing located: the walk keeps its Wi-Fi scans
    if not has_wifi:
        reason = "no Wi-Fi fingerprints in the bundle"
    elif any(sc is not None for sc in steps.scans or ()):
        reason = "no Wi-Fi scan of the walk located"
    else:
        reason = "no Wi-Fi scans in the walk"
    return WalkRadio(ble_steps, pos, "ble", how, reason, "BLE")
