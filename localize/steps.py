"""Per-step sensor summaries: what the localizer consumes, one record per detected step.

The survey side (:mod:`survey.step_summaries`) turns a trace into :class:`StepSummaries`; a phone
or a server streams one :class:`StepSummary` at a time into :meth:`Localizer.step`. Both are
plain numpy (no pandas), so the runtime stays light.

Conventions: times in Unix ms; headings are azimuths in degrees clockwise from map north (+y);
the field features are those of :mod:`survey.field_features` (strength uT, azimuth of the
horizontal field deg, polar angle from up deg), averaged over the step cycle (the interval from
the previous step to this one).
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.bundle import RSSI_RANGE_DBM, rssi_reading
from localize.errors import LocalizationError
from localize.params import is_number

__all__ = ["AttitudeCode", "RadioScan", "StepSummaries", "StepSummary", "attitude_codes",
           "ble_transmitter_ids"]


class AttitudeCode(IntEnum):
    """Phone attitude of a step as a small integer (names as in :mod:`survey.attitude`)."""

    UNKNOWN = 0
    UFH = 1
    UFNH = 2
    UNF = 3
    NOT_UPWARD = 4
    #: Not upward, with the top edge up or down (a swinging hand, a pocket): the compass is
    #: the walking axis, either way along it (:mod:`survey.carried_heading`).
    CARRIED = 5


_NAMES = {"UNKNOWN": 0, "UFH": 1, "UFNH": 2, "UNF": 3, "NU": 4, "NOT_UPWARD": 4, "CARRIED": 5}


def attitude_codes(names: ArrayLike) -> NDArray[np.int8]:
    """Attitude names (``"UFH"``, ``"UNF"``, ``"NU"``, ...) to :class:`AttitudeCode` values.

    Unknown names map to ``UNKNOWN`` (0).

    Examples
    --------
    >>> attitude_codes(["UFH", "NU", "?"]).tolist()
    [1, 4, 0]
    """
    arr = np.asarray(names, dtype=object).ravel()
    return np.array([_NAMES.get(str(a), 0) for a in arr], dtype=np.int8)


def ble_transmitter_ids(key: ArrayLike, mac: ArrayLike | None = None) -> NDArray[np.str_]:
    """Transmitter ids of BLE sightings: ``uuid:major:minor@mac`` (lower case).

    The beacon key alone is not unique in practice: on the real site1 traces 285 beacons (MAC
    addresses) share 19 keys, 1,845 of 2,189 F1 windows hearing the one key
    ``9195b3ad-...:0:0``, and fingerprints keyed that way locate no better than chance (52 m
    median). With the MAC the same data gives 6.4 m. Without a MAC column the key is used.
    """
    k = np.char.lower(np.asarray(key).astype(str))
    if mac is None:
        return k
    m = np.char.lower(np.asarray(mac).astype(str))
    return np.where(m != "", np.char.add(np.char.add(k, "@"), m), k)


@dataclass(frozen=True)
class RadioScan:
    """One Wi-Fi (or BLE) scan: transmitter keys and RSSI.

    Attributes
    ----------
    t_ms : int
        Scan time (Unix ms).
    keys : ndarray of str, shape (k,)
        BSSIDs (colon separated) or beacon keys; unique within the scan. Lower-cased on
        construction, as the bundles keep them.
    rssi_dbm : ndarray of float, shape (k,)
        Received signal strength (dBm), within :data:`~localize.bundle.RSSI_RANGE_DBM`
        (else a LocalizationError naming the scan and the key).
    age_ms : ndarray of float, shape (k,), optional
        Age of each row at the scan time (ms): Android reports, with every scan, transmitters
        last heard up to several seconds before it, and those rows lag the walker. NaN (or no
        array) = unknown, treated as fresh.
    """

    t_ms: int
    keys: NDArray[np.str_]
    rssi_dbm: NDArray[np.float64]
    age_ms: NDArray[np.float64] | None = None

    def __repr__(self) -> str:  # what the scan is, not its arrays
        strongest = f", strongest {np.max(self.rssi_dbm):.0f} dBm" if len(self.keys) else ""
        return f"RadioScan(t_ms={self.t_ms}, {len(self.keys)} transmitters{strongest})"

    def __post_init__(self) -> None:
        keys = np.asarray(self.keys)
        if keys.ndim != 1:  # a key given alone ("ab") is no list of keys
            raise LocalizationError(f"scan at {self.t_ms}: keys must be a list of transmitter "
                                    f"ids, got {self.keys!r}")
        if np.ndim(self.rssi_dbm) != 1 or len(keys) != len(self.rssi_dbm):
            raise LocalizationError(f"scan at {self.t_ms}: {keys.size} keys but "
                                    f"{np.size(self.rssi_dbm)} RSSI values (one per key)")
        if self.age_ms is not None and np.size(self.age_ms) != len(keys):
            raise LocalizationError(f"scan at {self.t_ms}: {len(keys)} keys but "
                                    f"{np.size(self.age_ms)} row ages")
        # BSSIDs and beacon ids are matched lower-case, as the bundles keep them: a phone or
        # tool that writes them upper-case must not miss (or mis-match) every transmitter
        lower = [str(k).lower() for k in keys.tolist()]
        if len(set(lower)) != len(lower):
            twice = next(k for i, k in enumerate(lower) if k in lower[:i])
            raise LocalizationError(f"scan at {self.t_ms}: key {twice} appears twice (keys "
                                    "are matched lower-case)")
        object.__setattr__(self, "keys", np.array(lower, dtype=str))
        try:
            rssi = np.asarray(self.rssi_dbm, dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise LocalizationError(f"scan at {self.t_ms}: RSSI values are not numbers "
                                    f"({err})") from err
        bad = ~rssi_reading(rssi)
        if bad.any():
            lo, hi = RSSI_RANGE_DBM
            i = int(np.flatnonzero(bad)[0])
            why = ("is a driver's 'no reading', no signal a phone receives: leave such rows "
                   "out" if rssi[i] == 0 else f"is not in [{lo:g}, {hi:g}) dBm (another unit?)")
            raise LocalizationError(f"scan at {self.t_ms}: RSSI {rssi[i]:g} dBm of "
                                    f"{self.keys[i]} {why}")

    def __len__(self) -> int:
        return len(self.keys)

    def time_or(self, step_t_ms: float) -> float:
        """The scan's own time (Unix ms), else ``step_t_ms`` (a scan without a time, 0)."""
        return float(self.t_ms or step_t_ms)

    def fresh(self, max_age_ms: float) -> RadioScan:
        """The scan without the rows older than ``max_age_ms`` (rows of unknown age stay)."""
        if self.age_ms is None:
            return self
        keep = ~(np.asarray(self.age_ms, dtype=np.float64) > max_age_ms)
        if keep.all():
            return self
        # rows of a checked scan: no need to check them again (this runs at every locate)
        subset = object.__new__(RadioScan)
        for name, value in (("t_ms", self.t_ms), ("keys", np.asarray(self.keys)[keep]),
                            ("rssi_dbm", np.asarray(self.rssi_dbm)[keep]),
                            ("age_ms", np.asarray(self.age_ms)[keep])):
            object.__setattr__(subset, name, value)
        return subset


def attach_scans(step_t_ms: NDArray, scans: Sequence[RadioScan]) -> list[RadioScan | None]:
    """One slot per step (times ``step_t_ms``, ms): each scan in the first step at or after
    its time; of two scans within one step, the later; a scan after the last step dropped."""
    slots: list[RadioScan | None] = [None] * len(step_t_ms)
    for scan in sorted(scans, key=lambda sc: sc.t_ms):
        i = int(np.searchsorted(step_t_ms, scan.t_ms, side="left"))
        if i < len(slots):
            slots[i] = scan
    return slots


@dataclass(frozen=True)
class StepSummary:
    """The sensor summary of one step (scalars, plus optional raw samples and a scan).

    Attributes
    ----------
    t_ms : float
        Step time (Unix ms).
    frequency_hz : float
        Step frequency (Hz); NaN when unknown (the filter uses its nominal frequency).
    delta_acc_ms2 : float
        Peak-to-valley acceleration swing of the step (m/s^2), for Weinberg-type models.
    compass_deg : float
        Compass heading of the phone over the step (deg clockwise from map north).
    turn_deg : float
        Heading change over the step (deg), clockwise positive (a right turn), as the
        compass counts; from the gyroscope when available, else the compass.
    strength_ut, azimuth_deg, polar_deg : float
        Earth-frame field features averaged over the step cycle; NaN when not measured.
    attitude : int
        :class:`AttitudeCode` of the step.
    relative_heading_deg : float
        Gyroscope heading (deg clockwise, unwrapped, arbitrary origin); NaN without a
        gyroscope.
    mag_strength_ut : ndarray or None
        Raw magnetometer strength samples of the step cycle (uT), for DTW matching.
    scan : RadioScan or None
        A Wi-Fi/BLE scan that arrived during the step.
    """

    t_ms: float
    frequency_hz: float
    delta_acc_ms2: float
    compass_deg: float
    turn_deg: float
    strength_ut: float
    azimuth_deg: float
    polar_deg: float
    attitude: int = int(AttitudeCode.UNKNOWN)
    relative_heading_deg: float = float("nan")
    mag_strength_ut: NDArray[np.float64] | None = field(default=None, repr=False)
    scan: RadioScan | None = None


_FLOAT_COLUMNS = ("frequency_hz", "delta_acc_ms2", "compass_deg", "turn_deg", "strength_ut",
                  "azimuth_deg", "polar_deg", "relative_heading_deg")


def _is_real(v: object) -> bool:
    """A real number (:func:`~localize.params.is_number`, and a 0-d numeric array)."""
    if isinstance(v, np.ndarray):
        return v.ndim == 0 and v.dtype.kind in "iuf"
    return is_number(v)


#: The :class:`AttitudeCode` values, as a streamed step's ``attitude`` may give them.
_ATTITUDE_VALUES = frozenset(float(a) for a in AttitudeCode)


def check_step_numbers(step_t_ms: object, **values: object) -> None:
    """Refuse a streamed step whose ``values`` (field name -> value) are not all real numbers
    (NaN, not None, for what is unknown): a LocalizationError naming the step's time
    ``step_t_ms`` and the field."""
    at = f"step at {step_t_ms} ms" if _is_real(step_t_ms) else "step"
    for name, v in values.items():
        if not _is_real(v):
            raise LocalizationError(f"{at}: {name} must be a number (NaN when unknown), not "
                                    f"{v!r}; the step was not taken")


#: The number fields of a :class:`StepSummary`.
STEP_NUMBER_FIELDS = ("t_ms", *_FLOAT_COLUMNS)


def check_step_values(s: StepSummary, numbers_read: Sequence[str] = STEP_NUMBER_FIELDS
                      ) -> None:
    """Refuse a streamed step whose fields are not what :class:`StepSummary` says, before a
    localizer takes any of it: ``t_ms`` and the float fields real numbers (NaN, not None,
    for what is unknown), ``attitude`` an :class:`AttitudeCode`, ``mag_strength_ut`` None or
    a 1-D array of numbers, ``scan`` None or a :class:`RadioScan`. A None compass used to
    break a particle filter for good: its particles were moved to NaN before it failed.
    ``numbers_read``: the number fields the method reads (the radio alone reads ``t_ms``;
    the others may then be None).

    Raises
    ------
    LocalizationError
        Naming the step's time and the field.
    """
    check_step_numbers(s.t_ms, **{name: getattr(s, name) for name in numbers_read})
    at = f"step at {s.t_ms} ms"
    if not _is_real(s.attitude) or float(s.attitude) not in _ATTITUDE_VALUES:
        raise LocalizationError(f"{at}: attitude must be one of the AttitudeCode values "
                                f"{[int(a) for a in AttitudeCode]}, not {s.attitude!r}; the "
                                "step was not taken")
    if s.mag_strength_ut is not None:
        raw = np.asarray(s.mag_strength_ut)
        if raw.ndim != 1 or raw.dtype.kind not in "fiu":
            raise LocalizationError(f"{at}: mag_strength_ut must be None or a 1-D array of "
                                    f"numbers (uT), not {raw.ndim}-D of {raw.dtype}; the step "
                                    "was not taken")
    if s.scan is not None and not isinstance(s.scan, RadioScan):
        raise LocalizationError(f"{at}: scan must be None or a RadioScan, not "
                                f"{type(s.scan).__name__}; the step was not taken")
    if s.scan is not None:
        problem = fix_time_problem(s.scan.t_ms, s.t_ms)
        if problem:
            raise LocalizationError(f"{at}: its scan {problem}; the step was not taken")


#: How far (ms) a step's scan or fix may be stamped after the step: a scan belongs to the
#: first step at or after it (:func:`survey.step_summaries.step_summaries`), and a streaming
#: app's clocks may differ by a little. One stamped an hour ahead (a time zone, a server's
#: receipt time) was kept by the alignment for the rest of the walk, pulling every position.
MAX_FIX_AFTER_STEP_MS = 2_000.0


def fix_time_problem(fix_t_ms: object, step_t_ms: float, *, zero_is_none: bool = True
                     ) -> str | None:
    """Why a scan's or fix's time cannot be a step's (a phrase), or None: not a finite
    time at or after 0 (0 or None: no time of its own, a :class:`RadioScan`'s way; with
    ``zero_is_none`` False, as a fix's time, 0 is no time), or more than
    :data:`MAX_FIX_AFTER_STEP_MS` after the step's time ``step_t_ms``."""
    if fix_t_ms is None or (_is_real(fix_t_ms) and float(fix_t_ms) == 0):
        return None if zero_is_none else "time 0 is no Unix time in ms"
    if not _is_real(fix_t_ms) or not 0 < float(fix_t_ms) < 2.0 ** 53:
        return f"time {fix_t_ms!r} is no Unix time in ms"
    ahead = float(fix_t_ms) - float(step_t_ms)
    if ahead > MAX_FIX_AFTER_STEP_MS:
        return (f"is stamped {float(fix_t_ms):.0f} ms, {ahead / 1000:.3g} s after the step "
                "(another clock, or a receipt time?): a scan is its step's when it comes "
                "at or before it")
    return None


#: The per-step columns a table of step summaries holds
#: (:func:`survey.step_summaries.summaries_table`, :meth:`StepSummaries.from_table`).
TABLE_COLUMNS = ("t_ms", *_FLOAT_COLUMNS, "attitude")


@dataclass(frozen=True)
class StepSummaries:
    """The steps of one walk, column-wise; every array has shape (m,).

    Attributes
    ----------
    t_ms : ndarray of float
        Step times (Unix ms), strictly increasing.
    frequency_hz, delta_acc_ms2, compass_deg, turn_deg, strength_ut, azimuth_deg, polar_deg,
    relative_heading_deg : ndarray of float
        As in :class:`StepSummary`.
    attitude : ndarray of int8
        :class:`AttitudeCode` per step.
    mag_offsets : ndarray of int64, shape (m + 1,), optional
        Step ``i``'s raw magnetometer samples are ``mag_strength_ut[mag_offsets[i]:
        mag_offsets[i + 1]]``.
    mag_strength_ut : ndarray of float, optional
        Raw magnetometer strength samples of all steps, concatenated (uT).
    scans : tuple of (RadioScan or None), optional
        One entry per step: the scan that arrived during that step, if any.
    trace_id, site_id, floor_id, floor_name : str
        Where the walk was recorded (from the trace header; empty when unknown).
    """

    t_ms: NDArray[np.float64]
    frequency_hz: NDArray[np.float64]
    delta_acc_ms2: NDArray[np.float64]
    compass_deg: NDArray[np.float64]
    turn_deg: NDArray[np.float64]
    strength_ut: NDArray[np.float64]
    azimuth_deg: NDArray[np.float64]
    polar_deg: NDArray[np.float64]
    attitude: NDArray[np.int8]
    relative_heading_deg: NDArray[np.float64] | None = None
    mag_offsets: NDArray[np.int64] | None = None
    mag_strength_ut: NDArray[np.float64] | None = None
    scans: tuple[RadioScan | None, ...] | None = None
    trace_id: str = ""
    site_id: str = ""
    floor_id: str = ""
    floor_name: str = ""
    extra: dict = field(default_factory=dict, compare=False)

    def __repr__(self) -> str:  # what the walk is, not its arrays
        scans = sum(s is not None for s in self.scans or ())
        span = f", {(self.t_ms[-1] - self.t_ms[0]) / 1000:.0f} s" if len(self.t_ms) else ""
        floor = self.floor_name or self.floor_id
        return (f"StepSummaries(trace_id={self.trace_id!r}, floor={floor!r}, "
                f"{len(self.t_ms)} steps{span}, {scans} scans, "
                f"magnetometer={self.has_magnetometer})")

    def __post_init__(self) -> None:
        m = len(np.asarray(self.t_ms))
        obj = object.__setattr__
        obj(self, "t_ms", np.asarray(self.t_ms, dtype=np.float64).ravel())
        if self.relative_heading_deg is None:
            obj(self, "relative_heading_deg", np.full(m, np.nan))
        for name in _FLOAT_COLUMNS:
            arr = np.asarray(getattr(self, name), dtype=np.float64).ravel()
            if len(arr) != m:
                raise LocalizationError(f"step summaries: column {name} has {len(arr)} values, "
                                        f"t_ms has {m}")
            obj(self, name, arr)
        att = np.asarray(self.attitude).ravel()
        if len(att) != m:
            raise LocalizationError(f"step summaries: attitude has {len(att)} values, t_ms {m}")
        obj(self, "attitude", att.astype(np.int8))
        if not np.all(np.isfinite(self.t_ms)) or np.any(np.diff(self.t_ms) <= 0):
            raise LocalizationError("step summaries: step times must be finite and strictly "
                                    "increasing")
        if not np.all(np.isfinite(self.compass_deg)):
            raise LocalizationError("step summaries: every step needs a finite compass heading")
        if (self.mag_offsets is None) != (self.mag_strength_ut is None):
            raise LocalizationError("step summaries: mag_offsets and mag_strength_ut go "
                                    "together")
        if self.mag_offsets is not None:
            off = np.asarray(self.mag_offsets, dtype=np.int64).ravel()
            raw = np.asarray(self.mag_strength_ut, dtype=np.float64).ravel()
            if (len(off) != m + 1 or (m and (off[0] != 0 or off[-1] != len(raw)))
                    or np.any(np.diff(off) < 0)):
                raise LocalizationError("step summaries: mag_offsets must be non-decreasing "
                                        "from 0 to len(mag_strength_ut), one more than steps")
            obj(self, "mag_offsets", off)
            obj(self, "mag_strength_ut", raw)
        if self.scans is not None:
            if len(self.scans) != m:
                raise LocalizationError(f"step summaries: {len(self.scans)} scan slots for {m} "
                                        "steps")
            obj(self, "scans", tuple(self.scans))

    @classmethod
    def from_table(cls, table, **meta: str) -> StepSummaries:
        """Step summaries from a table of their columns (a pandas DataFrame, a pyarrow Table
        or a dict of arrays), as :func:`survey.step_summaries.summaries_table` writes them;
        ``meta``: ``trace_id``, ``site_id``, ``floor_id``, ``floor_name``. Scans and raw
        magnetometer samples are not in a table (:meth:`with_scans` adds scans).

        Raises
        ------
        LocalizationError
            A column missing. ``relative_heading_deg`` is required too: without the
            gyroscope's heading the alignment walks on the compass alone, and its error on
            the real traces grew by a third (a notebook round trip lost it silently).
        """
        have = set(table.column_names if hasattr(table, "column_names") else table.keys())
        missing = [n for n in TABLE_COLUMNS if n not in have]
        if missing:
            raise LocalizationError(f"step summaries: the table lacks column(s) "
                                    f"{', '.join(missing)}")
        return cls(**{name: np.asarray(table[name]) for name in TABLE_COLUMNS}, **meta)

    def __len__(self) -> int:
        return len(self.t_ms)

    @property
    def has_magnetometer(self) -> bool:
        """Whether any step carries a measured field strength."""
        return bool(np.isfinite(self.strength_ut).any())

    def __getitem__(self, i: int) -> StepSummary:
        """Step ``i`` (a whole number; negative from the end) as a :class:`StepSummary`."""
        try:
            if isinstance(i, (bool, np.bool_)):
                raise TypeError
            i = operator.index(i)
        except TypeError:
            raise TypeError(f"StepSummaries index must be a whole number (one step), not "
                            f"{type(i).__name__}; iterate, or take the arrays "
                            "(steps.t_ms[:3], ...) for several") from None
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(f"step {i} out of range for {len(self)} steps")
        raw = None
        if self.mag_offsets is not None:
            raw = self.mag_strength_ut[self.mag_offsets[i]:self.mag_offsets[i + 1]]
        return StepSummary(
            t_ms=float(self.t_ms[i]), frequency_hz=float(self.frequency_hz[i]),
            delta_acc_ms2=float(self.delta_acc_ms2[i]), compass_deg=float(self.compass_deg[i]),
            turn_deg=float(self.turn_deg[i]), strength_ut=float(self.strength_ut[i]),
            azimuth_deg=float(self.azimuth_deg[i]), polar_deg=float(self.polar_deg[i]),
            attitude=int(self.attitude[i]),
            relative_heading_deg=float(self.relative_heading_deg[i]),
            mag_strength_ut=raw, scan=None if self.scans is None else self.scans[i])

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def with_columns(self, **columns) -> StepSummaries:
        """A copy with some columns replaced (e.g. smoothed strength)."""
        from dataclasses import replace

        return replace(self, **columns)

    def with_scans(self, scans: Sequence[RadioScan]) -> StepSummaries:
        """A copy carrying ``scans`` instead of its own: each attached to the first step at or
        after its time, as :func:`survey.step_summaries.step_summaries` attaches Wi-Fi scans
        (two scans within one step: the later one; a scan after the last step is dropped).

        Examples
        --------
        >>> s = StepSummaries(t_ms=[0.0, 500.0, 1000.0], frequency_hz=[2.0] * 3,
        ...                   delta_acc_ms2=[3.0] * 3, compass_deg=[0.0] * 3, turn_deg=[0.0] * 3,
        ...                   strength_ut=[40.0] * 3, azimuth_deg=[0.0] * 3,
        ...                   polar_deg=[30.0] * 3, attitude=[1, 1, 1])
        >>> scan = RadioScan(700, np.array(["b1"]), np.array([-70.0]))
        >>> [sc is not None for sc in s.with_scans([scan]).scans]
        [False, False, True]
        """
        return self.with_columns(scans=tuple(attach_scans(self.t_ms, scans)))
