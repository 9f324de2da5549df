"""Walking axis of steps on which the phone is carried with its top edge up or down.

The compass heading of a step is the heading of the phone's top edge (``y`` axis) projected
to the horizontal (:func:`survey.rotation.heading_deg`). That is the walking direction when the
phone is held in front of the body (flat or tilted towards the eyes), but not when it hangs in a
swinging hand (``y`` down) or sits upright in a trouser pocket (``y`` up): the top edge then
points up or down, its horizontal projection is small, and the swing tips it forward and back
so that its heading flips by 180 deg from step to step.

For such *steep* step cycles (the ``y`` axis within ``steep_deg`` of the mean vertical over
the stride, this cycle and the one before it) this module takes the heading of a device axis
that stays horizontal through the swing (``-z``, made perpendicular to that mean vertical: an
arm or a thigh swings the phone about a horizontal axis, which leaves that axis's heading
alone), and turns it onto the walking axis: the principal axis of the horizontal acceleration
in the earth frame (the arm or thigh swings along the walking direction), taken relative to the
reference axis so that turns do not blur it, over the trailing ``window_steps`` cycles.

The result is an *axis*: whether the walker goes one way along it or the other is not decided
here (the phase of the forward push within the step, paper 001's event E1, tells it only when
the step events mark the heel strikes, which a swinging arm's own accelerations upset). Step
summaries mark such steps :attr:`localize.steps.AttitudeCode.CARRIED`, and the localizers try
both ways. Only past and present cycles enter a step's value, so a streaming client computes
the same values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from survey.rotation import interpolate_rotation_vector, rotation_matrices

__all__ = ["CarriedHeadingParams", "carried_heading_deg"]


@dataclass(frozen=True)
class CarriedHeadingParams:
    """Options of :func:`carried_heading_deg`.

    Attributes
    ----------
    steep_deg : float
        A step cycle is steep when the phone's ``y`` axis lies within this angle (deg) of the
        cycle's mean vertical. Phones held in front of the body, even tilted 60-70 deg towards
        the eyes, stay below it; a hanging or pocketed phone, swinging +-35 deg, averages to
        a vertical ``y`` axis.
    window_steps : int
        Trailing step cycles whose accelerations give the walking axis's angle to the
        reference axis (cycles that are not steep add nothing).
    """

    steep_deg: float = 20.0
    window_steps: int = 16

    def __post_init__(self) -> None:
        if not 0.0 < self.steep_deg < 90.0:
            raise ValueError(f"steep_deg must be in (0, 90), got {self.steep_deg}")
        if self.window_steps < 2:
            raise ValueError(f"window_steps must be >= 2, got {self.window_steps}")


def _trailing_sum(per_cycle: NDArray, n: int) -> NDArray:
    """Sums of the trailing ``n`` entries (fewer at the start), along axis 0."""
    c = np.concatenate([np.zeros((1,) + per_cycle.shape[1:], per_cycle.dtype),
                        np.cumsum(per_cycle, axis=0)])
    i = np.arange(len(per_cycle))
    return c[i + 1] - c[np.maximum(i - n + 1, 0)]


def carried_heading_deg(acc_t_ms: NDArray, acc_xyz: NDArray, rot_t_ms: NDArray, rot: NDArray,
                        cycle_start_ms: NDArray, step_t_ms: NDArray,
                        params: CarriedHeadingParams = CarriedHeadingParams()
                        ) -> NDArray[np.float64]:
    """Walking axis of the steep step cycles (see the module docstring).

    Parameters
    ----------
    acc_t_ms, acc_xyz : ndarray, shapes (n,) and (n, 3)
        Accelerometer times (ms, sorted) and specific force in the device frame (m/s^2).
    rot_t_ms, rot : ndarray, shapes (m,) and (m, 3|4)
        Rotation-vector times (ms, sorted) and Android rotation vectors.
    cycle_start_ms, step_t_ms : ndarray, shape (k,)
        Each step cycle's start and end (the step event), ms; cycles do not overlap.
    params : CarriedHeadingParams

    Returns
    -------
    ndarray, shape (k,)
        Degrees clockwise from the rotation vector's north, in [0, 360), on steep cycles (one
        of the axis's two directions, the same one all along the walk while the phone keeps
        its hold); NaN on the others and on cycles without accelerometer samples.
    """
    acc_t = np.asarray(acc_t_ms, dtype=np.float64)
    start = np.asarray(cycle_start_ms, dtype=np.float64)
    end = np.asarray(step_t_ms, dtype=np.float64)
    k = len(end)
    out = np.full(k, np.nan)
    if k == 0 or len(acc_t) == 0:
        return out
    cyc = np.searchsorted(end, acc_t, side="left")  # the cycle of every sample, k if none
    inside = cyc < k
    inside[inside] = acc_t[inside] > start[cyc[inside]]
    if not inside.any():
        return out
    cyc, t = cyc[inside], acc_t[inside]
    acc = np.asarray(acc_xyz, dtype=np.float64)[inside]
    r = rotation_matrices(interpolate_rotation_vector(rot_t_ms, rot, t), quaternion=True)
    n_of = np.bincount(cyc, minlength=k).astype(np.float64)

    def cycle_sum(v: NDArray) -> NDArray:
        if np.iscomplexobj(v):
            return cycle_sum(v.real) + 1j * cycle_sum(v.imag)
        return np.bincount(cyc, weights=v, minlength=k)

    # the earth's up axis in device coordinates, averaged over the stride (two cycles: the
    # swing's forward and backward halves)
    up = _trailing_sum(np.column_stack([cycle_sum(r[:, 2, j]) for j in range(3)]), 2)
    norm = np.linalg.norm(up, axis=1)
    up = up / np.where(norm > 0, norm, 1.0)[:, None]
    steep = (n_of > 0) & (norm > 0) & (np.abs(up[:, 1]) > np.cos(np.radians(params.steep_deg)))
    if not steep.any():
        return out
    # reference axis: -z made perpendicular to that mean vertical (horizontal on average)
    ref = np.array([0.0, 0.0, -1.0]) + up[:, 2:3] * up
    ref /= np.linalg.norm(ref, axis=1)[:, None]  # |up_z| < sin(steep_deg) on steep cycles
    sel = steep[cyc]
    cyc, r, acc = cyc[sel], r[sel], acc[sel]
    ref_e = np.einsum("nij,nj->ni", r, ref[cyc])
    # horizontal vectors as complex numbers north + i east, so that arg is the heading
    ref_c = ref_e[:, 1] + 1j * ref_e[:, 0]
    ref_c /= np.maximum(np.abs(ref_c), 1e-12)
    acc_e = np.einsum("nij,nj->ni", r, acc)
    rel = (acc_e[:, 1] + 1j * acc_e[:, 0]) * np.conj(ref_c)  # turned into the reference's frame
    count = np.maximum(n_of, 1)
    centred = rel - (cycle_sum(rel) / count)[cyc]
    spread = _trailing_sum(cycle_sum(centred ** 2) / count, params.window_steps)
    # the principal axis; its doubled angle unwrapped from cycle to cycle keeps one way along
    # it throughout the walk, even when the axis lies across the reference
    axis = 0.5 * np.unwrap(np.angle(spread[steep]))
    heading = np.angle(cycle_sum(ref_c))[steep] + axis
    out[steep] = np.mod(np.degrees(heading), 360.0)
    return out
