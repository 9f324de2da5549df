"""The radio model a walk is localized with: the bundle's fingerprints, calibrated for the
walk's phone.

A phone model in the bundle's device table (fitted on Wi-Fi) uses its stored RSSI map
``calibrated = k * rssi + b``; any other phone, and BLE, is calibrated online from the walk's
first :data:`ONLINE_CALIBRATION_SCANS` scans (a search for the ``(k, b)`` most consistent with
the map, no positions needed) when at least :data:`MIN_CALIBRATION_SCANS` of them hear enough
known transmitters, else left uncalibrated. Positioners are cached per bundle id: bundles are
content-addressed, so the cache cannot go stale, and a folder of walks builds each bundle's
positioner once.
"""

from __future__ import annotations

from collections.abc import Sequence

from localize.bundle import MapBundle
from localize.fingerprint_positioner import FingerprintPositioner
from localize.steps import RadioScan

__all__ = ["MIN_CALIBRATION_SCANS", "ONLINE_CALIBRATION_SCANS", "bundle_positioner",
           "radio_for_walk"]

#: Scans of a walk used to calibrate an unknown phone's RSSI online.
ONLINE_CALIBRATION_SCANS = 8
#: Fewer usable scans than this leave the phone uncalibrated: from one BLE window the search
#: found k = 1.7, b = +74 dB and tripled the walk's error (6.79 m against 2.14 m uncalibrated).
MIN_CALIBRATION_SCANS = 3

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
    and how it was calibrated (a sentence for logs).

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
    cal = pos.online_calibration(first)
    if cal.n_scans < MIN_CALIBRATION_SCANS:
        return pos, (f"uncalibrated ({cal.n_scans} of the first {len(first)} scans hear enough "
                     f"known transmitters to calibrate from; {MIN_CALIBRATION_SCANS} needed)")
    return pos.with_calibration(cal.k, cal.b), \
        f"online from {cal.n_scans} scans (k={cal.k:.3f}, b={cal.b:+.1f} dB)"
