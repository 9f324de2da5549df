"""The walk-line format's radio logs: a walk's Wi-Fi scans and BLE sightings as CSVs beside
its sensor CSV (``wifi_log`` and ``ble_log`` in its plan; ``docs/walkline_format.md``), read
into the store's Wi-Fi and BLE tables with the trace reader's checks and rules.

Wi-Fi log: one row per access point heard in a scan; the rows of one ``t_ms`` are one scan.

=============  ========  ===========================================================
column         required  meaning
=============  ========  ===========================================================
t_ms           yes       scan time (Unix ms)
bssid          yes       the access point's MAC address (``aa:bb:..``, ``AA-BB-..``, 12 hex)
rssi_dbm       yes       received strength (dBm, within [-127, 0); 0 is no reading; rounded to whole dBm)
freq_mhz       no        channel frequency (MHz); 0 in the store when absent or 0 (unknown)
ssid           no        network name
last_seen_ms   no        when the phone last heard it (Unix ms); the scan time when absent
=============  ========  ===========================================================

BLE log: one row per beacon sighting (iBeacon ids).

=============  ========  ===========================================================
column         required  meaning
=============  ========  ===========================================================
t_ms           yes       time (Unix ms)
uuid           yes       proximity UUID
major, minor   yes       within [0, 65535]
rssi_dbm       yes       received strength (dBm, within [-127, 0); 0 is no reading; rounded to whole dBm)
tx_power_dbm   no        the beacon's calibrated power (dBm); 0 in the store when absent
distance_m     no        the phone's distance estimate (m); NaN when absent
mac            no        the beacon's MAC address
last_seen_ms   no        when the phone last heard it (Unix ms); ``t_ms`` when absent
=============  ========  ===========================================================
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pyarrow as pa
from numpy.typing import NDArray

from .trace_format import (
    BLE_COLUMNS,
    BLE_DTYPES,
    WIFI_COLUMNS,
    WIFI_DTYPES,
    ParseReport,
    empty_table,
)
from .trace_reader import (
    beacon_row_checks,
    beacon_table,
    drop_repeats,
    wifi_row_checks,
    wifi_table,
)
from .walkline_csv import MAX_TIME_MS, LogTable, RowCheck, good_rows, read_log_csv, time_check

WIFI_REQUIRED = ("t_ms", "bssid", "rssi_dbm")
BLE_REQUIRED = ("t_ms", "uuid", "major", "minor", "rssi_dbm")
_NOT_A_NUMBER = "non-numeric, missing or non-finite value"


class _Numbers:
    """A log's number columns, checked as the rows they make bad (``bad``: per column, the
    rows whose value is given but not a number, or missing where it is required)."""

    def __init__(self, log: LogTable) -> None:
        self.log = log
        self.bad: list[tuple[str, NDArray[np.bool_]]] = []

    def take(self, name: str, *, default: NDArray[np.float64] | float | None = None,
             whole: bool = True) -> NDArray[np.float64]:
        """Column ``name`` as float64 (n_rows,); an absent column or an empty value is
        ``default`` (required when None). A value that is not a finite number (or, ``whole``,
        not a whole number) marks its row bad."""
        log = self.log
        values = log.numbers(name)
        empty = log.missing(name)
        bad = ~empty & ~np.isfinite(values)
        if whole:
            bad |= ~empty & np.isfinite(values) & (values != np.round(values))
        if default is None:
            bad |= empty
        else:
            values = np.where(empty, default, values)
        self.bad.append((name, bad))
        return values

    def rows(self) -> NDArray[np.bool_]:
        """Rows with a bad number (n_rows,)."""
        return np.logical_or.reduce([bad for _, bad in self.bad]) if self.bad else \
            np.zeros(self.log.n_rows, dtype=bool)


def _checks(log: LogTable, numbers: _Numbers, t_ms: NDArray[np.float64],
            seen_ms: NDArray[np.float64], refused: list[tuple[str, str, NDArray[np.bool_]]],
            columns: list[list[tuple[str, NDArray[np.bool_]]]],
            reference_ms: float) -> list[RowCheck]:
    """The rows of a radio log refused: numbers, then the trace reader's checks
    (``refused``; ``columns``, per check, the rows each column makes bad), then the time."""
    not_numbers = numbers.rows()
    checks = [RowCheck("non_numeric", _NOT_A_NUMBER, not_numbers, numbers.bad)]
    late = ~not_numbers & (t_ms >= MAX_TIME_MS)
    seen = ~not_numbers & ~((seen_ms >= 0) & (seen_ms < MAX_TIME_MS))
    beyond = late | seen
    checks.append(RowCheck("out_of_range", "a time outside [0, 2^53) ms", beyond,
                           [("t_ms", late), ("last_seen_ms", seen)]))
    taken = not_numbers | beyond
    for (reason, detail, rows), named in zip(refused, columns):
        rows = rows & ~taken
        checks.append(RowCheck(reason, detail, rows, named))
        taken |= rows
    checks.append(time_check(log, t_ms, ~taken, reference_ms))
    return checks


def parse_wifi_csv(data: bytes, *, reference_ms: float, report: ParseReport,
                   path: str = "<input>", strict: bool = False) -> pd.DataFrame:
    """A walk-line Wi-Fi log as the store's Wi-Fi table (:data:`WIFI_COLUMNS`: one row per
    access point and scan, sorted by scan time and BSSID). Rows are checked as the trace
    reader checks ``TYPE_WIFI`` lines (BSSID, RSSI, frequency, last-seen time), and a row
    more than 12 h from ``reference_ms`` (the walk's time, Unix ms) is a ``time_outlier``;
    bad rows and dropped repeats (a BSSID listed twice in a scan) are counted in ``report``.

    Raises
    ------
    SurveyFormatError
        Not a readable CSV, a required column missing, rows none of which is usable, rows
        on another clock than the plan's; strict mode: any bad row.
    """
    log = read_log_csv(data, path, "Wi-Fi log", WIFI_REQUIRED, ("bssid", "ssid"))
    numbers = _Numbers(log)
    t = numbers.take("t_ms")
    rssi = np.round(numbers.take("rssi_dbm", whole=False))
    freq = numbers.take("freq_mhz", default=0.0)
    seen = numbers.take("last_seen_ms", default=np.nan_to_num(t))
    # absent, empty or 0 (what the store keeps for unknown): unknown, not refused
    given_freq = ~log.missing("freq_mhz") & (freq != 0)
    cols = {"t_ms": t, "rssi_dbm": rssi, "last_seen_ms": seen, "bssid": log.texts("bssid"),
            "freq_mhz": np.where(given_freq, freq, 1.0)}
    bssid, refused = wifi_row_checks(cols)
    columns = [[(c, rows)] for c, (_, _, rows)
               in zip(("bssid", "rssi_dbm", "freq_mhz", "last_seen_ms"), refused)]
    checks = _checks(log, numbers, t, seen, refused, columns, reference_ms)
    good = good_rows(log, checks, report, strict=strict, row_name="WIFI_ROW", empty_ok=True)
    if not good.any():
        return empty_table(WIFI_COLUMNS, WIFI_DTYPES)
    keep = pa.array(np.flatnonzero(good))
    table, _, dropped, other_clock = wifi_table(np.zeros(int(good.sum()), dtype=np.int64), {
        "t_ms": t[good].astype(np.int64), "last_seen_ms": seen[good].astype(np.int64),
        "rssi_dbm": rssi[good].astype(np.int64), "freq_mhz": freq[good].astype(np.int64),
        "ssid": log.texts("ssid").take(keep), "bssid": bssid.take(keep)})
    if len(dropped):
        report.dropped["duplicate_bssid_in_scan"] = len(dropped)
    if len(other_clock):
        report.dropped["wifi_last_seen_other_clock"] = len(other_clock)
    return table


def parse_ble_csv(data: bytes, *, reference_ms: float, report: ParseReport,
                  path: str = "<input>", strict: bool = False) -> pd.DataFrame:
    """A walk-line BLE log as the store's BLE table (:data:`BLE_COLUMNS`, sorted by time;
    a beacon's key is ``uuid:major:minor``). Rows are checked as the trace reader checks
    ``TYPE_BEACON`` lines (RSSI, major and minor, TX power), a row without a UUID is refused
    and a row more than 12 h from ``reference_ms`` (the walk's time, Unix ms) is a
    ``time_outlier``; bad rows and dropped repeats (a row repeated whole) are counted in
    ``report``.

    Raises
    ------
    SurveyFormatError
        As :func:`parse_wifi_csv`.
    """
    log = read_log_csv(data, path, "BLE log", BLE_REQUIRED, ("uuid", "mac"))
    numbers = _Numbers(log)
    t = numbers.take("t_ms")
    cols = {"t_ms": t, "rssi_dbm": np.round(numbers.take("rssi_dbm", whole=False)),
            "major": numbers.take("major"), "minor": numbers.take("minor"),
            "tx_power_dbm": numbers.take("tx_power_dbm", default=0.0),
            "distance_m": numbers.take("distance_m", default=np.nan, whole=False),
            "last_seen_ms": numbers.take("last_seen_ms", default=np.nan_to_num(t))}
    numbers.bad.append(("uuid", log.missing("uuid")))
    refused = beacon_row_checks(cols)
    columns = [[("rssi_dbm", refused[0][2])],
               [(c, ~((cols[c] >= 0) & (cols[c] < 2**16))) for c in ("major", "minor")]
               + [("tx_power_dbm", refused[1][2])]]
    checks = _checks(log, numbers, t, cols["last_seen_ms"], refused, columns, reference_ms)
    good = good_rows(log, checks, report, strict=strict, row_name="BLE_ROW", empty_ok=True)
    if not good.any():
        return empty_table(BLE_COLUMNS, BLE_DTYPES)
    keep = pa.array(np.flatnonzero(good))
    kept = {c: v[good] if c == "distance_m" else v[good].astype(np.int64)
            for c, v in cols.items()}
    table, files = beacon_table(np.zeros(int(good.sum()), dtype=np.int64), {
        **kept, "uuid": log.texts("uuid").take(keep), "mac": log.texts("mac").take(keep)})
    table, _, dropped = drop_repeats(table, files)
    if len(dropped):
        report.dropped["duplicate_beacon"] = len(dropped)
    return table.reset_index(drop=True)
