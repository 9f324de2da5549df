"""How the phone is held and what its inertial sensors feel (noise-free physics).

The attitude ``q`` rotates device coordinates into the earth frame (E, N, Up). Device axes: ``x``
to the right of the screen, ``y`` to its top, ``z`` out of the screen. Holding modes:

- ``"flat_forward"`` (UFH in paper 001): flat in front of the body, ``y`` forward, rolled ~3.5 deg
  and pitched ~0.5 deg with gait sway (median tilt ~4 deg; the real traces' accelerometer means
  are a_x ~ -0.6, a_y ~ 0 m/s^2);
- ``"upward_not_flat"``: upright in front of the body, screen to the user, pitched ~55 deg (48-62);
- ``"swinging"``: hanging in the hand (``y`` down), swinging with the arm at the stride rate;
- ``"pocket"``: upright in a trouser pocket (``y`` up), swinging with the thigh.

The accelerometer feels ``f = a - g`` (specific force: +9.81 m/s^2 up at rest) in the device frame;
the walking signal is a vertical bounce at the step frequency (1-3 m/s^2), a forward surge and a
lateral sway at the stride frequency (half the step frequency). The gyroscope feels the device's
angular velocity. Sensor errors are added in :mod:`~survey.sim.devices`; the Android rotation
vector (which also includes the compass deviation) is :func:`rotation_vector`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SimulationError
from . import rotations as rot
from .signals import smooth_noise
from .walker import WalkKinematics

HOLDING_MODES: tuple[str, ...] = ("flat_forward", "upward_not_flat", "swinging", "pocket")
GRAVITY_MPS2 = 9.80665


@dataclass(frozen=True)
class ImuParams:
    """Gait signal and rotation-vector error parameters.

    Attributes
    ----------
    bounce_mps2 : (float, float)
        Clip range of the vertical bounce amplitude (m/s^2); the amplitude grows with step
        frequency.
    surge_ratio : float
        Forward surge amplitude relative to the bounce.
    sway_mps2 : float
        Lateral sway amplitude at the stride frequency (m/s^2).
    rv_yaw_noise_deg : float
        SD of the slowly wandering yaw error of the rotation vector (deg).
    rv_yaw_corr_s : float
        Correlation time of that yaw error (s).
    rv_tilt_noise_deg : float
        SD of the rotation vector's tilt error (deg).
    """

    bounce_mps2: tuple[float, float] = (1.0, 3.0)
    surge_ratio: float = 0.55
    sway_mps2: float = 0.6
    rv_yaw_noise_deg: float = 1.0
    rv_yaw_corr_s: float = 4.0
    rv_tilt_noise_deg: float = 0.3


def holding_attitude(kin: WalkKinematics, mode: str, rng: np.random.Generator
                     ) -> tuple[np.ndarray, np.ndarray]:
    """True device attitude for a holding mode.

    Parameters
    ----------
    kin : WalkKinematics
    mode : str
        One of :data:`HOLDING_MODES`.
    rng : numpy.random.Generator

    Returns
    -------
    q : numpy.ndarray, shape (n, 4)
        Device-to-earth quaternions (x, y, z, w), w >= 0.
    swing_rad : numpy.ndarray, shape (n,)
        Pendulum angle of the arm/leg carrying the phone (0 unless swinging or in a pocket).
    """
    if mode not in HOLDING_MODES:
        raise SimulationError(f"unknown holding mode {mode!r}; expected one of {HOLDING_MODES}")
    n = len(kin.t_s)
    rate = 1.0 / max(np.median(np.diff(kin.t_s)), 1e-3) if n > 1 else 50.0
    ph = kin.step_phase
    m = kin.moving
    c = rng.uniform(0.0, 2.0 * np.pi, 4)
    slow_yaw = smooth_noise(n, 3.0 * rate, rng)
    slow_pitch = smooth_noise(n, 2.0 * rate, rng)
    slow_roll = smooth_noise(n, 2.0 * rate, rng)
    stride = np.sin(np.pi * ph + c[0])          # one period per two steps
    step = np.sin(2.0 * np.pi * ph + c[1])
    swing = np.zeros(n)
    if mode == "flat_forward":
        az = kin.heading_deg + 2.0 * slow_yaw + 1.5 * m * stride
        # the real surveyors' phone: mean a_x ~ -0.6 m/s^2 (rolled ~3.5 deg), mean a_y ~ 0
        pitch = rng.normal(0.5, 1.5) + 1.0 * slow_pitch + 0.8 * m * step
        roll = rng.normal(3.5, 0.7) + 1.0 * slow_roll + 1.2 * m * np.sin(np.pi * ph + c[2])
    elif mode == "upward_not_flat":
        az = kin.heading_deg + 2.5 * slow_yaw + 2.0 * m * stride
        pitch = float(np.clip(rng.normal(55.0, 3.0), 48.0, 62.0)) + 2.0 * slow_pitch + 2.0 * m * step
        roll = rng.normal(0.0, 3.0) + 1.5 * slow_roll + 1.5 * m * np.sin(np.pi * ph + c[2])
    elif mode == "swinging":
        swing = np.radians(35.0) * m * stride
        az = kin.heading_deg + rng.normal(0.0, 5.0) + 4.0 * slow_yaw
        pitch = -90.0 + np.degrees(swing) + 2.0 * slow_pitch
        roll = rng.normal(0.0, 5.0) + 3.0 * slow_roll
    else:  # pocket
        swing = np.radians(25.0) * m * stride
        az = kin.heading_deg + rng.normal(0.0, 15.0) + 2.0 * slow_yaw
        pitch = 90.0 - np.degrees(swing) + 1.0 * slow_pitch
        roll = rng.normal(0.0, 8.0) + 2.0 * slow_roll
    q = rot.canonical(rot.from_yaw_pitch_roll(az, pitch, roll))
    return q, swing


def specific_force(kin: WalkKinematics, q: np.ndarray, swing_rad: np.ndarray, mode: str,
                   params: ImuParams, rng: np.random.Generator) -> np.ndarray:
    """Noise-free accelerometer reading (m/s^2) in the device frame, shape (n, 3).

    Walking accelerations are built in the earth frame from the gait phase, then gravity is added
    and the sum rotated into the device frame.
    """
    n = len(kin.t_s)
    ph = kin.step_phase
    m = kin.moving
    f = kin.step_freq_hz
    f_mean = float(np.mean(f)) if n else 1.8
    bounce = np.clip(1.0 + 2.5 * (f_mean - 1.5), *params.bounce_mps2) * rng.uniform(0.85, 1.15)
    bounce = bounce * (f / f_mean) ** 2
    # vertical peak at heel strike (integer phase); forward push peaks late in the step cycle,
    # just before the next heel strike; the lateral push keeps its side for a whole step and
    # alternates from step to step (period of a stride)
    vertical = bounce * m * (np.cos(2 * np.pi * ph)
                             + 0.3 * np.cos(4 * np.pi * ph + rng.uniform(0, 2 * np.pi)))
    dvdt = np.gradient(kin.speed_mps, kin.t_s) if n > 1 else np.zeros(n)
    push_phase = rng.normal(0.85, 0.04)
    forward = params.surge_ratio * bounce * m * np.cos(2 * np.pi * (ph - push_phase)) + dvdt
    lateral = params.sway_mps2 * m * np.sin(np.pi * ph + rng.normal(0.0, 0.25))
    if mode in ("swinging", "pocket") and n > 1:
        arm = 0.6 if mode == "swinging" else 0.45
        dsw = np.gradient(swing_rad, kin.t_s)
        forward = forward + arm * np.gradient(dsw, kin.t_s) * np.cos(swing_rad)
        vertical = vertical + arm * dsw ** 2
    h = np.radians(kin.heading_deg)
    fwd_e, fwd_n = np.sin(h), np.cos(h)
    acc_earth = np.column_stack([
        forward * fwd_e + lateral * fwd_n,          # right of heading = (cos h, -sin h)
        forward * fwd_n - lateral * fwd_e,
        vertical + GRAVITY_MPS2,
    ])
    return rot.rotate_inverse(q, acc_earth)


def angular_rate(kin: WalkKinematics, q: np.ndarray) -> np.ndarray:
    """Noise-free gyroscope reading (rad/s) in the device frame, shape (n, 3)."""
    return rot.body_rates(q, kin.t_s)


def rotation_vector(q_true: np.ndarray, deviation_deg: np.ndarray, t_s: np.ndarray,
                    params: ImuParams, rng: np.random.Generator) -> np.ndarray:
    """Android's fused attitude as the phone reports it.

    The fusion aligns the device with the *local* magnetic field, so its azimuth is the true
    azimuth minus the local compass deviation (in the reported frame the field's horizontal
    component points north, as in the real data), plus a slowly wandering yaw error and a small
    tilt error.

    Parameters
    ----------
    q_true : numpy.ndarray, shape (n, 4)
        True device-to-earth attitude.
    deviation_deg : numpy.ndarray, shape (n,)
        Compass deviation at the true positions (see
        :meth:`~survey.sim.field.MagneticField.compass_deviation_deg`).
    t_s : numpy.ndarray, shape (n,)
    params : ImuParams
    rng : numpy.random.Generator

    Returns
    -------
    numpy.ndarray, shape (n, 4)
        (x, y, z, w) with w >= 0: x, y, z are the rotation-vector values written to the trace.
    """
    n = len(t_s)
    rate = 1.0 / max(np.median(np.diff(t_s)), 1e-3) if n > 1 else 50.0
    yaw_err = params.rv_yaw_noise_deg * smooth_noise(n, params.rv_yaw_corr_s * rate, rng)
    tilt_x = params.rv_tilt_noise_deg * smooth_noise(n, 0.5 * rate, rng)
    tilt_y = params.rv_tilt_noise_deg * smooth_noise(n, 0.5 * rate, rng)
    # rotating the earth frame by +deviation about up lowers every azimuth by the deviation
    q_yaw = rot.from_axis_angle(rot.E_Z, np.radians(np.asarray(deviation_deg) - yaw_err))
    q_tilt = rot.multiply(rot.from_axis_angle(rot.E_X, np.radians(tilt_x)),
                          rot.from_axis_angle(rot.E_Y, np.radians(tilt_y)))
    return rot.canonical(rot.multiply(q_tilt, rot.multiply(q_yaw, q_true)))
