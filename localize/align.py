"""Offline walk alignment: a recorded walk's step track fitted to its radio fixes and walls.

When the whole walk is at hand (a recorded walk, crowd-sourced data, evaluation), its shape is
known far better than its place: the gyroscope's heading changes and the steps give a track
whose shape is about 1 m off over a whole ILC walk once rotated, scaled and shifted right, while
the walk's Wi-Fi fixes, with errors correlated along the walk, leave its place 2.7 m off
(``benchmarks/localize_bound.py``). The floor plan decides much of the rest: a track of the
right shape fits into the corridors at few places. :class:`WalkAligner` therefore searches the
similarity transform ``x(t) = shift + a * shape(t)`` (``a`` a complex factor: rotation and
scale) that maximises

- the likelihood of the fixes under a correlated error model (a persistent part plus an AR(1)
  part per axis, generalised least squares; ``AlignParams.fix_*``),
- minus ``wall_weight`` times the mean squared distance (m^2) of the track's step positions
  from the reachable mask (0 on it, capped at ``wall_cap_m``): a step a little off the mask,
  as the shape's errors put some, costs little, a track through a building much,
- Gaussian priors on the rotation (the compass anchor's error) and the log scale (the step
  model's error),

over a coarse grid (rotation, scale, shift on a ``shift_step_m`` grid around each transform's
best shift) and then a finer one around the best, by branch and bound: the fixes and the
priors bound a transform's score from above, so the track is laid over the mask only for
the transforms that can still win. Offline one alignment of the whole walk gives every
position; in real time the walk so far is aligned again at every step.

The shape: each step moves ``step_length_nominal_m * (swing / weinberg_nominal)`` (Weinberg's
acceleration swing ``(a_max - a_min)^(1/4)``; the nominal length when the swing is unknown)
along the gyroscope heading, turned onto the compass by the circular mean of the compass
minus the gyroscope heading over the walk (the compass heading itself where a step has no
gyroscope heading). When most steps carry their phone top edge up or down (a swinging hand, a
pocket: :attr:`~localize.steps.AttitudeCode.CARRIED`), their compass is the walking axis,
either way along it, and the rotations are searched around 180 deg as well as around 0.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from weakref import WeakKeyDictionary

import numpy as np
from numpy.typing import NDArray

from localize.bundle import Grid, MapBundle
from localize.errors import LocalizationError
from localize.filter import BaseLocalizer, check_step, check_within_reach, walk_fixes
from localize.maps import mean_heading_offset_deg
from localize.params import MAX_STEP_M
from localize.radio import RadioModel
from localize.steps import (AttitudeCode, RadioScan, StepSummaries, StepSummary,
                            check_step_numbers, fix_time_problem)
from localize.track import Estimate, Track

__all__ = ["AlignParams", "WalkAligner", "distance_from_mask_m", "walk_shape"]


@dataclass(frozen=True)
class AlignParams:
    """Parameters of :class:`WalkAligner` (lengths m, angles deg, times s).

    The fix error model (per axis: ``fix_persistent_sd_m`` shared by all fixes of a walk plus
    an AR(1) part of ``fix_ar_sd_m`` decaying over ``fix_ar_tau_s``) is the fit to the ILC
    fixes' error correlations in docs/localize.md ("How far the Wi-Fi fixes can take it").
    """

    rotation_range_deg: float = 15.0
    rotation_step_deg: float = 2.5
    scale_range: tuple[float, float] = (0.75, 1.25)
    scale_step: float = 0.05
    #: Prior SD of the rotation (the compass anchor's error, deg).
    heading_sd_deg: float = 8.0
    #: Prior SD of the log scale (the step model's error for an unknown walker).
    scale_sd: float = 0.12
    step_length_nominal_m: float = 0.65
    #: Nominal Weinberg swing ``(a_max - a_min)^(1/4)`` ((m/s^2)^(1/4)).
    weinberg_nominal: float = 1.7
    #: Half-width (m) of the shift grid around each transform's best shift for the fixes.
    search_half_width_m: float = 8.0
    shift_step_m: float = 0.5
    fix_persistent_sd_m: float = 2.5
    fix_ar_sd_m: float = 3.85
    fix_ar_tau_s: float = 8.4
    #: Independent part of each fix's error (m), and the SD of a given start position (m).
    fix_white_sd_m: float = 0.5
    start_sd_m: float = 1.0
    #: Log-likelihood lost per m^2 of the track's mean squared distance from the reachable
    #: mask, and the distance (m) beyond which a position counts as that far.
    wall_weight: float = 10.0
    wall_cap_m: float = 10.0
    #: Log-likelihood lost per unit share of the track's positions off the mask: a sharper
    #: wall term for walks whose shape is much better than the ILC phones' (on the simulated
    #: site 40 with ``wall_weight=0`` does better; docs/localize.md, "Walk alignment").
    wall_share_weight: float = 0.0
    #: Real time: the alignment uses the last ``window_s`` of the walk's walking (s): a gap
    #: between steps counts for at most ``pause_counts_s``, so that a stop (a walker
    #: standing two minutes at a shop) does not empty the window of the walk's shape.
    window_s: float = 120.0
    pause_counts_s: float = 2.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            vals = v if isinstance(v, tuple) else (v,)
            if not all(np.isfinite(x) and x >= 0 for x in vals):
                raise LocalizationError(f"align parameter {f.name} must be finite and "
                                        f">= 0, got {v}")
        positive = ("rotation_step_deg", "scale_step", "heading_sd_deg", "scale_sd",
                    "step_length_nominal_m", "weinberg_nominal", "shift_step_m",
                    "fix_ar_tau_s", "fix_white_sd_m", "start_sd_m", "window_s", "pause_counts_s",
                    "wall_cap_m")
        bad = [n for n in positive if not getattr(self, n) > 0]
        if bad:
            raise LocalizationError(f"align parameters {bad} must be positive")
        lo, hi = self.scale_range
        if not 0 < lo <= hi:
            raise LocalizationError(f"scale_range must be 0 < low <= high, got {self.scale_range}")


def _headings(compass_deg: NDArray, gyro_deg: NDArray, axis: NDArray | None = None
              ) -> tuple[NDArray[np.float64], float, bool]:
    """Walking azimuth per step (rad), the turn (rad) that put the gyroscope heading onto
    the compass (the circular mean of their difference; the compass itself, turn 0, when a
    step has no gyroscope heading), and whether the walk may run the other way round.

    ``axis`` marks steps whose compass is the walking axis, either way along it (a carried
    phone, :attr:`~localize.steps.AttitudeCode.CARRIED`): the turn comes from the other steps,
    or, when those are fewer, from the axis steps, and the walk may then be turned by 180 deg.
    """
    compass, gyro = np.radians(compass_deg), np.radians(gyro_deg)
    axis = np.zeros(len(compass), bool) if axis is None else np.asarray(axis, bool)
    both_ways = bool(axis.sum() > (~axis).sum())
    if not np.isfinite(gyro).all():
        return compass, 0.0, both_ways
    use = axis if both_ways else ~axis
    turn = float(np.angle(np.mean(np.exp(1j * (compass[use] - gyro[use]))))) if use.any() \
        else 0.0
    return gyro + turn, turn, both_ways


def _moves(delta_acc_ms2: NDArray, heading_rad: NDArray, p: AlignParams
           ) -> NDArray[np.complex128]:
    """Each step's move (complex m): Weinberg length along the heading."""
    swing = np.maximum(delta_acc_ms2, 0.0) ** 0.25
    length = p.step_length_nominal_m * np.where(np.isfinite(swing), swing / p.weinberg_nominal,
                                                1.0)
    # a glitch (one accelerometer value of 1e30) must not throw the track across the map
    return np.minimum(length, MAX_STEP_M) * np.exp(1j * (np.pi / 2 - heading_rad))


def _shape(compass_deg: NDArray, gyro_deg: NDArray, delta_acc_ms2: NDArray, p: AlignParams,
           axis: NDArray | None = None) -> tuple[NDArray[np.complex128], float, bool]:
    """The step track of :func:`walk_shape` from its columns, the anchor turn (rad) and
    whether the track may run the other way round (:func:`_headings`)."""
    heading, anchor, both_ways = _headings(compass_deg, gyro_deg, axis)
    return (np.concatenate([[0j], np.cumsum(_moves(delta_acc_ms2, heading, p))]), anchor,
            both_ways)


def steps_shape(steps: StepSummaries, p: AlignParams, heading_offset_deg: float = 0.0
                ) -> tuple[NDArray[np.complex128], float, bool]:
    """:func:`_shape` of a whole walk's summaries, their compass less the floor's
    ``heading_offset_deg`` (:func:`localize.maps.mean_heading_offset_deg`)."""
    return _shape(steps.compass_deg - heading_offset_deg, steps.relative_heading_deg,
                  steps.delta_acc_ms2, p, steps.attitude == AttitudeCode.CARRIED)


def walk_shape(steps: StepSummaries, params: AlignParams = AlignParams()
               ) -> NDArray[np.complex128]:
    """The walk's step track in map orientation, up to the transform :class:`WalkAligner`
    fits: ``(m + 1,)`` complex positions (x east + i y north, m), 0 before the first step
    and after each step (module docstring: how)."""
    return steps_shape(steps, params)[0]


def _fix_covariance(t_s: NDArray, start_given: bool, p: AlignParams) -> NDArray[np.float64]:
    """Per-axis covariance (m^2) of the fixes at times ``t_s`` (s); with ``start_given`` the
    first is a given start position, independent of the others."""
    dt = np.abs(t_s[:, None] - t_s[None, :])
    cov = (p.fix_persistent_sd_m ** 2 + p.fix_ar_sd_m ** 2 * np.exp(-dt / p.fix_ar_tau_s)
           + p.fix_white_sd_m ** 2 * np.eye(len(t_s)))
    if start_given:
        cov[0, :] = cov[:, 0] = 0.0
        cov[0, 0] = p.start_sd_m ** 2
    return cov


def distance_from_mask_m(mask: NDArray[np.bool_], cell_m: float, cap_m: float
                         ) -> NDArray[np.float64]:
    """Distance (m) of every cell from the nearest ``True`` cell of ``mask`` (0 on it), at most
    ``cap_m``; the same shape as ``mask``.

    A chamfer distance: repeated relaxation over the 8 neighbours (steps of 1 and sqrt(2)
    cells), which over-estimates distances between the axes and the diagonals by at most
    8.3 %.
    """
    cap = float(cap_m) / float(cell_m)
    d = np.where(mask, 0.0, cap)
    if not mask.any():
        return d * cell_m
    h, w = d.shape
    pad = np.full((h + 2, w + 2), cap)
    moves = [(dr, dc, float(np.hypot(dr, dc))) for dr in (-1, 0, 1) for dc in (-1, 0, 1)
             if dr or dc]
    for _ in range(int(np.ceil(cap)) + 1):
        pad[1:-1, 1:-1] = d
        new = d.copy()
        for dr, dc, step in moves:
            np.minimum(new, pad[1 + dr:h + 1 + dr, 1 + dc:w + 1 + dc] + step, out=new)
        np.minimum(new, cap, out=new)
        if np.array_equal(new, d):
            break
        d = new
    return d * cell_m


class WallLookup:
    """The squared distance (m^2) of every cell of a grid from the reachable mask
    (:func:`distance_from_mask_m`), read for many shifts of a track at once.

    The table has a frame of one cell of the cap around the grid: a position off the grid
    is clipped into the frame. :meth:`at_shifts` reads every position at every shift of a
    square grid of shifts. When the shift step is a whole number of cells or of half cells,
    each position's values at all the shifts are one strided block of the table (split into
    half cells for the latter, and edge-padded by twice the largest shift; kept per split,
    step and reach: for an ILC floor 1.8 MB for the full search's 0.5 m shifts and 5.7 MB
    for the local search's 0.25 m), read in one gather; otherwise the cells are computed
    shift by shift. Both read the same cells.
    """

    #: Splits of a cell into sub-cells tried for a block read: powers of two, so that a
    #: position in sub-cells (``u * split``) is exact. Finer splits were measured: on an ILC
    #: floor a quarter-cell split (22 MB) read 0.125 m shifts only 10 % faster than cell by
    #: cell, its small blocks being far apart in the large table.
    SPLITS = (1, 2)

    def __init__(self, off_mask_m: NDArray, cell_m: float, cap_m: float) -> None:
        self.off2_pad = np.pad(off_mask_m, 1, constant_values=cap_m) ** 2
        self.off2_pad.flags.writeable = False
        self.cell_m = float(cell_m)
        # (split, m, reach) -> _strided_blocks
        self._blocks: dict[tuple[int, int, int], NDArray] = {}

    def at_shifts(self, u: NDArray[np.complex128], k: int, step_m: float
                  ) -> NDArray[np.float64]:
        """The table at the positions ``u`` (complex, in cells from the grid's origin,
        ``(P,)``) shifted by ``(i + 1j * j) * step_m`` for ``i, j`` in ``-k..k``: ``(P,
        (2k + 1)^2)``, shift ``(i, j)`` in column ``(j + k) * (2k + 1) + i + k``."""
        h, w = self.off2_pad.shape
        ratio = step_m / self.cell_m
        for split in self.SPLITS:
            m = int(round(ratio * split))
            if m >= 1 and abs(ratio * split - m) < 1e-9:
                break
        else:  # no split makes the step whole: cell by cell
            d = np.arange(-k, k + 1) * step_m / self.cell_m
            col = np.clip(np.floor(u.real[None, :] + d[:, None]) + 1, 0, w - 1).astype(np.intp)
            row = np.clip(np.floor(u.imag[None, :] + d[:, None]) + 1, 0, h - 1).astype(np.intp)
            row *= w
            return self.off2_pad.take(row[:, None, :] + col[None, :, :]).reshape(-1, len(u)).T
        # in sub-cells of 1 / split cell, shift (i, j) reads sub-cell floor(u * split) +
        # split (the frame) + m * (i, j), which lies in cell floor(u + ratio * (i, j)) + 1:
        # clip each position's central sub-cell to within the largest shift of the table and
        # read its block of a table edge-padded by twice that shift
        reach = k * m
        blocks = self._blocks.get((split, m, reach))
        if blocks is None:
            blocks = self._blocks[(split, m, reach)] = self._strided_blocks(split, m, reach)
        col = np.clip(np.floor(u.real * split) + split, -reach, w * split - 1 + reach)
        row = np.clip(np.floor(u.imag * split) + split, -reach, h * split - 1 + reach)
        return blocks[row.astype(np.intp) + reach, col.astype(np.intp) + reach].reshape(len(u), -1)

    def _strided_blocks(self, split: int, m: int, reach: int) -> NDArray[np.float64]:
        """A view ``(split h + 2 reach, split w + 2 reach, 2k + 1, 2k + 1)`` whose ``[r, c]``
        is the block of sub-cells ``(r - reach + m j, c - reach + m i)`` of the table split
        into ``split x split`` sub-cells and edge-padded by ``2 reach``, for
        :meth:`at_shifts`."""
        table = self.off2_pad
        if split > 1:
            table = np.repeat(np.repeat(table, split, axis=0), split, axis=1)
        padded = np.pad(table, 2 * reach, mode="edge")
        padded.flags.writeable = False
        size = 2 * reach + 1
        return np.lib.stride_tricks.sliding_window_view(padded, (size, size))[:, :, ::m, ::m]


#: Per bundle and cap: the :class:`WallLookup` of its mask, computed once (the CLI and the
#: benchmarks make one aligner per walk on the same bundle).
_WALL_CACHE: WeakKeyDictionary[MapBundle, dict[float, WallLookup]] = WeakKeyDictionary()


def _bundle_walls(bundle: MapBundle, cap_m: float) -> WallLookup:
    """The :class:`WallLookup` of the bundle's reachable mask, capped at ``cap_m``."""
    by_cap = _WALL_CACHE.setdefault(bundle, {})
    if cap_m not in by_cap:
        by_cap[cap_m] = WallLookup(
            distance_from_mask_m(bundle.mask, bundle.grid.cell_m, cap_m), bundle.grid.cell_m,
            cap_m)
    return by_cap[cap_m]


#: Steps before the real-time window's origin that :class:`WalkAligner` keeps before it
#: forgets them (in batches, so the lists are not shifted at every step).
_FORGET_STEPS = 64


class WalkAligner(BaseLocalizer):
    """Localizer by walk alignment: the step track fitted to the radio fixes and the walls.

    Real time (``run(steps)``, or ``start`` then ``step`` per step): at every step the track
    so far (its last ``window_s``) is aligned again, over the whole grid when the step brought
    a new radio fix, else around the last alignment (a new step can still meet a wall).
    Offline (``run(steps, smooth=True)``): one alignment of the whole walk gives every
    position; meant for walks of a few minutes, as one rotation and scale cannot follow the
    gyroscope's drift over much longer ones. A given start position counts as a fix
    of ``start_sd_m``; without one the walk's first fix is used from the start on, as the
    particle filters start from it. See the module docstring.

    Streaming gives ``run``'s track when it starts at ``run``'s start time
    (``t_ms=steps.t_ms[0] - 500``), from a given start or from a scan: ``start(scan=...)``
    dates the fix at the scan's own time, and ``step`` does not apply that scan again when
    its step brings it (the same object, or a scan with the same time). From another start
    time the track moves by a fraction of a metre (docs/localize.md).

    Parameters
    ----------
    bundle : MapBundle
        The floor's bundle (its reachable mask).
    params : AlignParams
    radio : RadioModel, optional
        Anything with ``locate(scan) -> (x, y, sigma)``; without it a start position is needed.
    """

    method = "align"
    can_smooth = True

    def __init__(self, bundle: MapBundle, params: AlignParams | None = None, *,
                 radio: RadioModel | None = None) -> None:
        super().__init__(bundle, radio=radio)
        self.params = params or AlignParams()
        self._walls = _bundle_walls(bundle, self.params.wall_cap_m)
        #: The floor's compass heading less walking direction (deg), taken off every compass
        #: heading when it is over the rotation prior's SD (``heading_sd_deg``), so that the
        #: rotations searched lie around the map's own north, not the compass's: a plan drawn
        #: along a building turned 70 deg from north was never aligned. A smaller offset is
        #: the prior's to cover: on ILC site1's floors (0.5-3.2 deg) taking it off cost 0.05 m
        #: of median error (3.08 -> 3.13 m, `benchmarks/localize_accuracy.py`).
        offset = mean_heading_offset_deg(bundle)
        self.heading_offset_deg = offset if abs(offset) > self.params.heading_sd_deg else 0.0
        self._reset(0.0)

    # -- streaming -------------------------------------------------------------------------
    def _reset(self, t0: float) -> None:
        self._t = [t0]
        self._compass: list[float] = []
        self._gyro: list[float] = []
        self._swing: list[float] = []
        self._axis: list[bool] = []
        self._fix_t: list[float] = []
        self._fix_z: list[complex] = []
        self._start_given = False
        self._start_scan: RadioScan | None = None  # the scan the start was located from
        self._pos = 0j          # current estimate (complex m)
        self._spread = self._full_spread = 0.0
        #: The RMS of the last search's finest shift grid (m; about 0.5): what the guided
        #: filter weighs the alignment with (``max(it, guide_sigma_m)``), as before the
        #: estimates' ``spread_m`` became the coarse grid's (session 50).
        self.search_spread_m = 0.0
        #: last alignment: (absolute rotation rad, scale, first index of its window in _t,
        #: its positions from there on)
        self._fit: tuple[float, float, int, NDArray[np.complex128]] | None = None
        self._stale = True

    def _start_at(self, x, y, t_ms, sigma, half_width_m) -> Estimate:
        self._reset(t_ms)
        self._fix_t.append(t_ms)
        self._fix_z.append(complex(x, y))
        self._start_given = sigma is None
        self._pos = complex(x, y)
        return Estimate(t_ms, x, y, 0.0 if sigma is None else float(sigma), 1.0, False,
                        self.bundle.floor_id)

    def _started_from(self, scan: RadioScan | None, t_fix_ms: float) -> None:
        """The start fix is dated at ``t_fix_ms`` (its scan's time, not the start's), and
        ``scan`` (if any) is not applied again by :meth:`step`."""
        self._fix_t[0] = float(t_fix_ms)
        self._start_scan = scan

    def _is_start_scan(self, scan: RadioScan) -> bool:
        first = self._start_scan
        return first is not None and (scan is first or bool(scan.t_ms)
                                      and scan.t_ms == first.t_ms)

    def step(self, s: StepSummary) -> Estimate:
        """Advance by one step (and its scan's fix, unless it is the start's scan) and return
        the new real-time estimate; see :meth:`step_values`."""
        check_step(s, self)
        self.check_next(s.t_ms, s.compass_deg)  # before the radio is asked
        located = (self.radio.locate(s.scan) if s.scan is not None and self.radio is not None
                   and not self._is_start_scan(s.scan) else None)
        fix = None if located is None else (located[0], located[1], s.scan.time_or(s.t_ms))
        return self._advance(s.t_ms, s.compass_deg, s.relative_heading_deg, s.delta_acc_ms2,
                             s.attitude == AttitudeCode.CARRIED, self._checked_fix(s.t_ms, fix))

    def step_values(self, t_ms: float, compass_deg: float, relative_heading_deg: float,
                    delta_acc_ms2: float, carried: bool = False,
                    fix: tuple[float, float, float] | None = None) -> Estimate:
        """:meth:`step` from a step's values instead of a :class:`StepSummary`: its time
        (Unix ms), compass and gyroscope headings (deg; gyroscope NaN: the compass alone),
        acceleration swing (m/s^2; NaN: the nominal step), whether the phone is carried
        (:attr:`AttitudeCode.CARRIED`), and a radio fix ``(x_m, y_m, t_ms)`` located by the
        caller (its scan time), each checked as :meth:`step` checks them. (The multi-user
        aligner checks a whole tick before any user moves, then takes the steps unchecked.)"""
        check_step_numbers(t_ms, t_ms=t_ms, compass_deg=compass_deg,
                           relative_heading_deg=relative_heading_deg,
                           delta_acc_ms2=delta_acc_ms2)
        self.check_next(t_ms, compass_deg)
        return self._advance(t_ms, compass_deg, relative_heading_deg, delta_acc_ms2,
                             bool(carried), self._checked_fix(t_ms, fix))

    def _checked_fix(self, t_ms: float, fix: tuple[float, float, float] | None
                     ) -> tuple[float, tuple[float, float]] | None:
        """A step's fix ``(x_m, y_m, t_ms)`` as :meth:`_advance` takes it, ``(t_ms, (x, y))``;
        a LocalizationError for one not finite, far off the map or stamped later than its
        step (:func:`~localize.steps.fix_time_problem`) (not taken)."""
        if fix is None:
            return None
        x, y, t = (float(v) for v in fix)
        late = fix_time_problem(t, t_ms, zero_is_none=False)
        if late and np.isfinite(t):
            raise LocalizationError(f"step at {t_ms:g} ms: fix {late}; the step was not taken")
        check_within_reach(self.bundle.grid, x if np.isfinite(t) else np.nan, y,
                           f"step at {t_ms:g} ms: fix ({x:g}, {y:g}, {t:g}) (x, y m, t ms)",
                           "; the step was not taken")
        return t, (x, y)

    def _advance(self, t_ms, compass_deg, gyro_deg, swing, axis, fix) -> Estimate:
        """Take one step (and its fix ``(t_ms, (x, y, sigma))``, if any), then align again:
        over the whole grid when a fix came, else around the last alignment (the new step
        can still meet a wall). Should the alignment fail, the step is taken back, so that
        the user carries on with the next one."""
        n_fixes, stale = len(self._fix_t), self._stale
        self._t.append(float(t_ms))
        self._compass.append(float(compass_deg) - self.heading_offset_deg)
        self._gyro.append(float(gyro_deg))
        self._swing.append(float(swing))
        self._axis.append(bool(axis))
        if fix is not None:
            self._fix_t.append(fix[0])
            self._fix_z.append(complex(fix[1][0], fix[1][1]))
            self._stale = True
        try:
            first = self._align_window(local=not self._stale)
        except Exception:  # nothing of the alignment's is kept before it succeeds
            for history in (self._t, self._compass, self._gyro, self._swing, self._axis):
                del history[-1]
            del self._fix_t[n_fixes:], self._fix_z[n_fixes:]
            self._stale = stale
            raise
        if first >= _FORGET_STEPS:
            self._forget(first)
        self._last = Estimate(self._t[-1], float(self._pos.real), float(self._pos.imag),
                              self._spread, 1.0, False, self.bundle.floor_id)
        return self._last

    def _align_window(self, local: bool) -> int:
        """Align the last ``window_s`` of the walk (its steps and fixes) and place the walker
        at its end; ``local`` searches only around the last alignment of the same window.
        Returns the window's first step index (what :meth:`_forget` may drop before it)."""
        p = self.params
        t = np.asarray(self._t)
        # walking time: a pause between steps counts for at most pause_counts_s (a 2 min
        # stop emptied the window: align 1.6 -> 3.8 m median on a simulated held-out walk)
        walked = np.concatenate([[0.0], np.cumsum(np.minimum(np.diff(t),
                                                             p.pause_counts_s * 1000.0))])
        first = max(min(int(np.searchsorted(walked, walked[-1] - p.window_s * 1000.0)),
                        len(t) - 1) - 1, 0)
        shape, anchor, both_ways = _shape(
            np.asarray(self._compass[first:]), np.asarray(self._gyro[first:]),
            np.asarray(self._swing[first:]), p, np.asarray(self._axis[first:]))
        times = t[first:]
        fix_t, fix_z = np.asarray(self._fix_t), np.asarray(self._fix_z)
        keep = fix_t >= times[0]
        start_given = self._start_given and bool(keep[0])
        if not keep.any():  # the window saw no fix: keep the latest one
            keep[-1] = True
        around = None
        if local and self._fit is not None and self._fit[2] <= first:
            rot, scale, fit_first, fit_pos = self._fit  # its position at this window's origin:
            around = (float(np.mod(np.degrees(rot - anchor) + 180.0, 360.0) - 180.0), scale,
                      fit_pos[first - fit_first])
        best = self._align(shape, times, fix_t[keep], fix_z[keep], start_given, both_ways,
                           around)
        pos = best.shift + best.factor * shape
        if around is None:  # a full search: its spread holds until the next one
            self._full_spread = best.spread_m
        self._pos, self._spread = pos[-1], max(best.spread_m, self._full_spread)
        self.search_spread_m = best.fine_spread_m
        self._fit = (float(np.angle(best.factor)) + anchor, abs(best.factor), first, pos)
        self._stale = False
        return first

    def _forget(self, first: int) -> None:
        """Drop the steps before index ``first`` of the step times (the current window's
        origin; no later window reaches back past it) and the fixes before that origin but
        the latest, so that memory and the work per step stay bounded however long a user
        walks. Every later alignment sees what it saw before (a test checks the tracks)."""
        del self._t[:first], self._compass[:first], self._gyro[:first]
        del self._swing[:first], self._axis[:first]
        rot, scale, fit_first, pos = self._fit
        self._fit = (rot, scale, fit_first - first, pos)
        old = [i for i, t in enumerate(self._fix_t[:-1]) if t < self._t[0]]
        if old and old[0] == 0:
            self._start_given = False  # a given start outside every later window
        for i in reversed(old):
            del self._fix_t[i], self._fix_z[i]

    def _align(self, shape: NDArray, times: NDArray, fix_t: NDArray, fix_z: NDArray,
               start_given: bool, both_ways: bool = False,
               around: tuple[float, float, complex] | None = None) -> _Best:
        at_fix = np.interp(fix_t, times, shape.real) + 1j * np.interp(fix_t, times, shape.imag)
        ci = np.linalg.inv(_fix_covariance(fix_t / 1000.0, start_given, self.params))
        return _Search(self.bundle.grid, self._walls, self.params, shape, fix_z, at_fix, ci,
                       both_ways).run(around)

    # -- batch -----------------------------------------------------------------------------
    def run(self, steps: StepSummaries, start_xy: tuple[float, float] | None = None, *,
            start_t_ms: float | None = None, half_width_m: float | None = None,
            smooth: bool = False) -> Track:
        """Localize a whole walk: real-time estimates, or with ``smooth`` one alignment of
        the whole walk (``half_width_m`` is ignored).

        Returns
        -------
        Track
            One estimate per step; ``spread_m`` is the RMS spread of the shift around the
            best alignment. Offline, ``info`` holds the fitted ``rotation_deg``, ``scale``,
            the number of fixes and the share of the track on the reachable mask.
        """
        self.check_run(steps, smooth, start_t_ms)
        t0 = float(steps.t_ms[0]) - 500.0 if start_t_ms is None else float(start_t_ms)
        fixes = walk_fixes(self.radio, steps)
        if start_xy is None and not fixes:
            raise LocalizationError(f"{steps.trace_id or 'walk'}: no start position given and "
                                    "no scan of the walk located by the radio model")
        if start_xy is not None:
            start = self._start_at(*self._checked_start(start_xy), t0, None, None)
        else:  # the first fix, at its own time, known from the start on
            _, t_fix, f = fixes[0]
            start = self._start_at(f[0], f[1], t0, f[2], None)
            self._started_from(None, t_fix)  # its scan is not among the later fixes
        later = fixes if start_xy is not None else fixes[1:]  # the start fix is in already
        self._set_start(start)  # what the step checks compare with
        track = (self._offline(steps, start, later) if smooth
                 else self._real_time(steps, start, later))
        track.info["seen_by_map"] = self.seen_by_map(steps)
        track.info.update(self.provenance())
        return track

    def _real_time(self, steps: StepSummaries, start: Estimate, later: list) -> Track:
        """The walk stepped through, aligned again at every step; ``later``: its fixes after
        the start's."""
        by_step = {i: (t, f) for i, t, f in later}
        axis = steps.attitude == AttitudeCode.CARRIED
        est = [self._advance(steps.t_ms[i], steps.compass_deg[i],
                             steps.relative_heading_deg[i], steps.delta_acc_ms2[i], axis[i],
                             by_step.get(i)) for i in range(len(steps))]
        track = Track.from_estimates(start, est, method=self.method, trace_id=steps.trace_id,
                                     floor_id=self.bundle.floor_id)
        track.info["smoothed"] = False
        return track

    def _offline(self, steps: StepSummaries, start: Estimate, later: list) -> Track:
        """One alignment of the whole walk; ``later``: its fixes after the start's."""
        shape, _, both_ways = steps_shape(steps, self.params, self.heading_offset_deg)
        times = np.concatenate([[start.t_ms], steps.t_ms])
        fix_t = np.asarray(self._fix_t + [t for _, t, _ in later])
        fix_z = np.asarray(self._fix_z + [complex(f[0], f[1]) for _, _, f in later])
        best = self._align(shape, times, fix_t, fix_z, self._start_given, both_ways)
        pos = best.shift + best.factor * shape
        n, floor = len(steps), self.bundle.floor_id
        first = Estimate(start.t_ms, float(pos[0].real), float(pos[0].imag), best.spread_m,
                         1.0, False, floor)
        track = Track(steps.t_ms.copy(), pos[1:].real.copy(), pos[1:].imag.copy(),
                      np.full(n, best.spread_m), np.ones(n), np.zeros(n, bool), first,
                      method=self.method, trace_id=steps.trace_id, floor_id=floor)
        track.info.update(smoothed=True, rotation_deg=float(np.degrees(np.angle(best.factor))),
                          scale=float(abs(best.factor)),
                          n_fixes=int(len(fix_t) - self._start_given),
                          inside_share=best.inside_share)
        return track


@dataclass
class _Best:
    score: float
    factor: complex
    shift: complex
    spread_m: float
    inside_share: float
    #: the spread over the finest grid searched (what spread_m was before session 50)
    fine_spread_m: float = 0.0


#: Log-likelihood below the best within which shifts are still placed for the spread.
SPREAD_MARGIN = 5.0


class _Search:
    """Grid search of ``(rotation, scale, shift)``; see :class:`WalkAligner`."""

    def __init__(self, grid: Grid, walls: WallLookup, p: AlignParams, shape: NDArray,
                 fix_z: NDArray, at_fix: NDArray, ci: NDArray, both_ways: bool = False) -> None:
        self.grid, self.walls = grid, walls  # the bundle's grid, the WallLookup of its mask
        self.both_ways = both_ways  # rotations near 180 deg are as likely as near 0
        self.p, self.shape, self.fix_z, self.at_fix = p, shape, fix_z, at_fix
        self.ci = ci
        self.ones_ci = ci.sum(axis=0)          # 1^T C^-1
        self.ones_ci_ones = float(ci.sum())    # 1^T C^-1 1

    def _fix_fit(self, a: NDArray) -> tuple[NDArray[np.float64], NDArray[np.complex128]]:
        """For the complex factors ``a`` (T,): the fixes' log-likelihood of a shift ``z`` is
        ``-0.5 * (q + ones_ci_ones * |z - g|^2)``; returns ``q`` (T,) and the generalised
        least-squares shift ``g`` (T,)."""
        resid = self.fix_z[None, :] - a[:, None] * self.at_fix[None, :]  # fix - shape, (T, F)
        g = (resid @ self.ones_ci) / self.ones_ci_ones
        r_ci_r = (((resid.real @ self.ci) * resid.real).sum(axis=1)
                  + ((resid.imag @ self.ci) * resid.imag).sum(axis=1))
        return r_ci_r - self.ones_ci_ones * np.abs(g) ** 2, g

    def _wall_values(self, a: complex, centre: complex, k: int, step_m: float
                     ) -> NDArray[np.float64]:
        """Squared distances (m^2) from the mask of the positions of the tracks ``centre +
        shift + a * shape`` for the shifts of :meth:`WallLookup.at_shifts`: ``(positions,
        shifts)``."""
        g = self.grid
        u = (centre + a * self.shape - complex(g.x0_m, g.y0_m)) / g.cell_m  # cell units
        return self.walls.at_shifts(u, k, step_m)

    def _walls_of(self, off2: NDArray) -> NDArray:
        """Wall penalty of each track from its :meth:`_wall_values` ``(positions, tracks)``."""
        pen = self.p.wall_weight * off2.mean(axis=0)
        if self.p.wall_share_weight:
            pen += self.p.wall_share_weight * (1.0 - (off2 == 0.0).mean(axis=0))
        return pen

    def run(self, around: tuple[float, float, complex] | None = None) -> _Best:
        """The best transform: over the whole coarse grid, or ``around`` a ``(rotation deg,
        scale, shift)`` (one coarse step each way, shifts within 1 m), then finer."""
        p = self.p
        if around is None:
            rot = np.arange(-p.rotation_range_deg, p.rotation_range_deg + 1e-9,
                            p.rotation_step_deg)
            if self.both_ways:
                rot = np.concatenate([rot, rot + 180.0])
            scale = np.arange(p.scale_range[0], p.scale_range[1] + 1e-9, p.scale_step)
            best = self._grid(rot, scale, p.search_half_width_m, p.shift_step_m)
        else:
            r0, s0, shift0 = around
            rot = r0 + np.arange(-1, 2) * p.rotation_step_deg
            if self.both_ways:  # the other way along the axis, from the same origin
                rot = np.concatenate([rot, rot + 180.0])
            scale = s0 + np.arange(-1, 2) * p.scale_step
            best = self._grid(rot, scale[scale > 0], 1.0, p.shift_step_m / 2, centre=shift0)
        # finer around the best: a fifth of the rotation and scale steps, half-step shifts
        # (read as blocks from the half-cell table; quarter steps cost 60 % of the time for
        # the same accuracy, docs/localize.md "Session 37")
        r0, s0 = np.degrees(np.angle(best.factor)), abs(best.factor)
        fine_rot = r0 + np.arange(-2, 3) * p.rotation_step_deg / 5
        fine_scale = s0 + np.arange(-2, 3) * p.scale_step / 5
        fine = self._grid(fine_rot, fine_scale[fine_scale > 0], p.shift_step_m,
                          p.shift_step_m / 2, centre=best.shift)
        # the spread is the coarse grid's, which spans the shifts the fixes and walls allow:
        # the fine grid's +-1 step gave about 0.5 m whatever the error
        chosen = fine if fine.score >= best.score else best
        return replace(chosen, spread_m=max(fine.spread_m, best.spread_m),
                       fine_spread_m=chosen.spread_m)

    def _grid(self, rot_deg: NDArray, scale: NDArray, half_width_m: float, step_m: float,
              centre: complex | None = None) -> _Best:
        """The best of the transforms ``rot_deg x scale x shifts``.

        Branch and bound: the fixes' likelihood plus the priors bounds each transform's
        score from above (the wall term is a penalty), so the tracks (the costly part) are
        placed only for transforms whose bound can still beat the best so far, taken in the
        order of their bounds; shifts within :data:`SPREAD_MARGIN` below the best are placed
        too, for the spread.
        """
        p = self.p
        k = int(np.floor(half_width_m / step_m + 1e-9))
        off = np.arange(-k, k + 1) * step_m
        grid = (off[None, :] + 1j * off[:, None]).ravel()   # (S,)
        r, s = np.repeat(rot_deg, len(scale)), np.tile(scale, len(rot_deg))  # every pair
        a = s * np.exp(1j * np.radians(r))
        q, g = self._fix_fit(a)
        centres = g if centre is None else np.full(len(a), complex(centre))
        dr = np.mod(r + 90.0, 180.0) - 90.0 if self.both_ways else r
        prior = -0.5 * (dr / p.heading_sd_deg) ** 2 - 0.5 * (np.log(s) / p.scale_sd) ** 2
        # each transform's best shift for the fixes: the grid point nearest its GLS shift
        to_g = (g - centres) / step_m
        nearest = centres + step_m * (np.clip(np.rint(to_g.real), -k, k)
                                      + 1j * np.clip(np.rint(to_g.imag), -k, k))
        tops = prior - 0.5 * (q + self.ones_ci_ones * np.abs(nearest - g) ** 2)
        best: _Best | None = None
        for i in np.argsort(-tops, kind="stable"):
            if best is not None and tops[i] <= best.score:
                break           # neither this transform nor any later one can win
            shifts = centres[i] + grid
            bound = prior[i] - 0.5 * (q[i] + self.ones_ci_ones * np.abs(shifts - g[i]) ** 2)
            keep = (np.flatnonzero(bound > best.score - SPREAD_MARGIN) if best is not None
                    else np.arange(len(bound)))
            ai = complex(a[i])
            off2 = self._wall_values(ai, complex(centres[i]), k, step_m)
            score = bound[keep] - self._walls_of(off2[:, keep])
            j = int(np.argmax(score))
            if best is None or score[j] > best.score:
                w = np.exp(score - score[j])
                w /= w.sum()
                d = shifts[keep] - np.sum(w * shifts[keep])
                spread = float(np.sqrt(np.sum(w * np.abs(d) ** 2)))
                best = _Best(float(score[j]), ai, complex(shifts[keep][j]), spread,
                             float((off2[:, keep[j]] == 0.0).mean()))
        assert best is not None
        return best
