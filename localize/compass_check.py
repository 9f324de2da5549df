"""Whether a walk's compass is turned against its radio fixes (a phone in another frame).

The localizers take the phone's compass heading (the azimuth of its y axis, from the Android
rotation vector) as the walking direction, up to the map's heading offset and a search of
+-15 deg (:class:`localize.align.AlignParams`). A phone held in landscape all along, a
rotation vector in another reference frame (iOS's ``xMagneticNorthZVertical``, x to north) or
an inverted quaternion turns every heading by tens of degrees: on four simulated walks so
logged every method was 11-12 m off (1.7 m as logged), exit 0, without a word.

:func:`compass_turn` fits the walk's step track (:func:`localize.align.walk_shape`) to its
fixes by a rotation, a scale and a shift (least squares, closed form) and compares it with the
fit without rotation. Where the track runs either way along its compass (a phone carried top
edge up or down) the rotation is taken modulo 180 deg. On ILC site1 the rotation over the
walks with 5 fixes or more is at most 44 deg (272 walks, median 6 deg); the four simulated
landscape walks give 82-101 deg.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from localize.align import AlignParams, steps_shape
from localize.filter import walk_fixes
from localize.radio import RadioModel
from localize.steps import StepSummaries

__all__ = ["CompassCheck", "compass_turn"]

#: The fit needs this many fixes over a track spreading this far (RMS about its mean, m).
MIN_FIXES, MIN_SPREAD_M = 5, 5.0
#: A turn this large (deg) that leaves at most this share of the unturned fit's squared
#: residual is said.
TURN_SAID_DEG, RESIDUAL_SHARE = 60.0, 0.5


@dataclass(frozen=True)
class CompassCheck:
    """The turn that fits a walk's step track to its radio fixes.

    Attributes
    ----------
    turn_deg : float
        Rotation of the track onto the fixes, deg, counter-clockwise on the map (the walk
        went this far anticlockwise of its compass, beyond the floor's heading offset),
        within (-180, 180] (within [-90, 90) for a track that runs either way along its
        compass).
    residual_share : float
        Squared residual of the turned fit over that of the best fit without a turn.
    n_fixes : int
    spread_m : float
        RMS spread of the track at the fixes' times about its mean (m).
    """

    turn_deg: float
    residual_share: float
    n_fixes: int
    spread_m: float

    @property
    def turned(self) -> bool:
        """The compass is turned: over :data:`TURN_SAID_DEG` and a fit far better turned."""
        return (abs(self.turn_deg) >= TURN_SAID_DEG and self.residual_share <= RESIDUAL_SHARE
                and self.spread_m >= MIN_SPREAD_M)  # (compass_turn needs MIN_FIXES)

    def mended(self, steps: StepSummaries) -> StepSummaries:
        """``steps`` with their compass turned by :attr:`turn_deg` onto the fixes (headings
        clockwise, so less the anticlockwise turn); the floor's heading offset stays in it,
        for the localizers to take off."""
        return replace(steps, compass_deg=(steps.compass_deg - self.turn_deg) % 360.0)

    def sentence(self) -> str:
        """What a warning says of it."""
        way = "anticlockwise" if self.turn_deg > 0 else "clockwise"
        return (f"its step track fits its {self.n_fixes} radio fixes only turned "
                f"{abs(self.turn_deg):.0f} deg {way} of its compass (a phone held in "
                "landscape, or a rotation vector in another frame than Android's?), so its "
                "track is likely far off")


def compass_turn(steps: StepSummaries, radio: RadioModel | None,
                 heading_offset_deg: float = 0.0) -> CompassCheck | None:
    """:class:`CompassCheck` of a walk's steps and the fixes ``radio`` gives its scans, the
    compass less the floor's ``heading_offset_deg`` (what the localizers take off it:
    :func:`localize.maps.mean_heading_offset_deg` of the walk's bundle; a plan drawn 70 deg
    from north is no turned phone); None without :data:`MIN_FIXES` fixes."""
    if radio is None or steps.scans is None or len(steps) < 2:
        return None
    fixes = [(t, f) for _, t, f in walk_fixes(radio, steps)]
    if len(fixes) < MIN_FIXES:
        return None
    shape, _, both_ways = steps_shape(steps, AlignParams(), heading_offset_deg)
    times = np.concatenate([[steps.t_ms[0] - 500.0], steps.t_ms])
    fix_t = np.array([t for t, _ in fixes], dtype=np.float64)
    a = np.interp(fix_t, times, shape.real) + 1j * np.interp(fix_t, times, shape.imag)
    z = np.array([complex(f[0], f[1]) for _, f in fixes])
    a, z = a - a.mean(), z - z.mean()
    saa = float(np.vdot(a, a).real)
    spread = float(np.sqrt(saa / len(a)))
    if saa == 0:
        return CompassCheck(0.0, 1.0, len(fixes), spread)
    c = np.vdot(a, z)  # sum conj(a) z: the best factor (rotation and scale) is c / saa
    turn = float(np.degrees(np.angle(c)))
    unturned = np.sum(np.abs(z - max(c.real, 0.0) / saa * a) ** 2)
    turned = np.sum(np.abs(z - c / saa * a) ** 2)
    if both_ways:  # its compass is the walking axis, either way along it
        turn = (turn + 90.0) % 180.0 - 90.0
        unturned = min(unturned, np.sum(np.abs(z - abs(c.real) / saa * a) ** 2))
    share = float(turned / unturned) if unturned > 0 else 1.0
    return CompassCheck(turn, share, len(fixes), spread)
