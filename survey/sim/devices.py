"""Phone models, individual phones, calibration sessions and the sensor error models.

Per phone: a soft-iron matrix ``S`` (near identity, a few %), a Wi-Fi RSSI distortion
``rssi_dev = k * rssi_ref + b`` (the reference phone has ``k = 1, b = 0``; paper 003 eq. 5) and a
small accelerometer offset. Per calibration session (a phone's day of surveying): the TRUE
hard-iron vector (jumps by tens of uT between sessions) and the bias the phone REPORTS, the true
one plus a residual of a few uT (larger in z, where a flat phone cannot observe it); both are
constant within a walk.

Magnetometer: ``raw = S @ (R^T B_earth) + h_true + noise``, quantized to the sensor's resolution;
``MAGNETIC_FIELD_UNCALIBRATED`` rows carry ``raw`` and the reported bias, ``MAGNETIC_FIELD``
rows ``raw - reported bias``. Accelerometer and gyroscope: the calibrated and the uncalibrated
stream are two readings with independent noise (as in the real traces, where they differ by
noise-sized amounts); the accelerometer's uncalibrated bias columns are zero, the gyroscope's
carry the phone's bias estimate.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..trace_format import SensorInfo
from . import rotations as rot


@dataclass(frozen=True)
class SensorSpec:
    """One declared sensor (a ``#\\ttype:N`` header line)."""

    type_code: int
    name: str
    vendor: str
    version: str
    resolution: float
    power_ma: float
    maximum_range: float

    def info(self) -> SensorInfo:
        """As the trace header's :class:`~survey.trace_format.SensorInfo`."""
        return SensorInfo(self.type_code, self.name, self.vendor, self.version,
                          self.resolution, self.power_ma, self.maximum_range)


def _imu(acc: tuple, gyr: tuple, mag: tuple) -> tuple[SensorSpec, ...]:
    """Sensor list in the real header order: accel, gyro, mag, then the uncalibrated ones."""
    a_name, a_vendor, a_ver, a_res, a_pow, a_max = acc
    g_name, g_vendor, g_ver, g_res, g_pow, g_max = gyr
    m_name, m_vendor, m_ver, m_res, m_pow, m_max = mag
    return (
        SensorSpec(1, a_name, a_vendor, a_ver, a_res, a_pow, a_max),
        SensorSpec(4, g_name, g_vendor, g_ver, g_res, g_pow, g_max),
        SensorSpec(2, m_name, m_vendor, m_ver, m_res, m_pow, m_max),
        SensorSpec(35, a_name + " Uncalibrated", a_vendor, a_ver, a_res, a_pow, a_max),
        SensorSpec(16, g_name + " Uncalibrated", g_vendor, g_ver, g_res, g_pow, g_max),
        SensorSpec(14, m_name + " Uncalibrated", m_vendor, m_ver, m_res, m_pow, m_max),
    )


@dataclass(frozen=True)
class DeviceModel:
    """A phone model: identity, declared sensors and noise levels.

    Attributes
    ----------
    brand, model, android_version, api_level : str
        Header values.
    sensors : tuple of SensorSpec
        Accelerometer, gyroscope, magnetometer, then their uncalibrated versions.
    accel_noise_mps2, gyro_noise_rps, mag_noise_ut : float
        White-noise SD of the readings.
    """

    brand: str
    model: str
    android_version: str
    api_level: str
    sensors: tuple[SensorSpec, ...]
    accel_noise_mps2: float = 0.05
    gyro_noise_rps: float = 0.004
    mag_noise_ut: float = 0.7

    @property
    def key(self) -> str:
        return f"{self.brand} {self.model}"

    @property
    def accel_resolution(self) -> float:
        return self.sensors[0].resolution

    @property
    def gyro_resolution(self) -> float:
        return self.sensors[1].resolution

    @property
    def mag_resolution(self) -> float:
        return self.sensors[2].resolution


#: Phone models the simulator knows: invented names and sensor descriptions (no real phone's
#: header is reproduced), with resolutions and noise levels typical of phone IMUs. The first
#: plays the survey's reference phone.
DEVICE_MODELS: dict[str, DeviceModel] = {m.key: m for m in (
    DeviceModel("SimPhone", "SIM-A1", "8.1.0", "27", _imu(
        ("SimA accelerometer", "indoormap-sim", "1", 0.0024, 0.2, 39.2),
        ("SimA gyroscope", "indoormap-sim", "1", 0.0011, 0.9, 34.9),
        ("SimA magnetometer", "indoormap-sim", "1", 0.6, 2.4, 4900.0)),
        mag_noise_ut=0.7),
    DeviceModel("SimPhone", "SIM-B2", "10", "29", _imu(
        ("SimB accelerometer", "indoormap-sim", "2", 0.0024, 0.25, 78.4),
        ("SimB gyroscope", "indoormap-sim", "2", 0.0012, 6.0, 17.5),
        ("SimB magnetometer", "indoormap-sim", "2", 0.06, 6.0, 4900.0)),
        accel_noise_mps2=0.04, gyro_noise_rps=0.003, mag_noise_ut=0.6),
    DeviceModel("SimPhone", "SIM-C3", "10", "29", _imu(
        ("SimC accelerometer", "indoormap-sim", "3", 0.0048, 0.17, 78.4),
        ("SimC gyroscope", "indoormap-sim", "3", 0.0012, 0.5, 34.9),
        ("SimC magnetometer", "indoormap-sim", "3", 0.15, 1.1, 4900.0)),
        accel_noise_mps2=0.06, gyro_noise_rps=0.005, mag_noise_ut=0.9),
    DeviceModel("SimPhone", "SIM-D4", "10", "29", _imu(
        ("SimD accelerometer", "indoormap-sim", "4", 0.0012, 0.23, 78.4),
        ("SimD gyroscope", "indoormap-sim", "4", 0.0012, 6.0, 34.9),
        ("SimD magnetometer", "indoormap-sim", "4", 0.15, 6.0, 4900.0)),
        accel_noise_mps2=0.05, gyro_noise_rps=0.004, mag_noise_ut=0.8),
)}


@dataclass(frozen=True)
class Device:
    """One phone used in the survey.

    Attributes
    ----------
    device_id : str
        ``"dev0"``, ``"dev1"``, ...
    model : DeviceModel
    reference : bool
        The survey's reference phone (``k = 1, b = 0``).
    soft_iron : tuple of tuple of float
        3x3 matrix ``S`` applied to the device-frame field.
    rssi_k, rssi_b : float
        Wi-Fi distortion ``rssi_dev = k * rssi_ref + b`` (dBm).
    accel_offset_mps2 : tuple of float
        Offset of the uncalibrated accelerometer (m/s^2), device frame.
    """

    device_id: str
    model: DeviceModel
    reference: bool
    soft_iron: tuple[tuple[float, float, float], ...]
    rssi_k: float
    rssi_b: float
    accel_offset_mps2: tuple[float, float, float]

    def to_dict(self) -> dict:
        return {"device_id": self.device_id, "brand": self.model.brand,
                "model": self.model.model, "reference": self.reference,
                "soft_iron": [list(r) for r in self.soft_iron],
                "rssi_k": self.rssi_k, "rssi_b": self.rssi_b,
                "accel_offset_mps2": list(self.accel_offset_mps2),
                "sensors": [asdict(s) for s in self.model.sensors],
                "noise": {"accel_mps2": self.model.accel_noise_mps2,
                          "gyro_rps": self.model.gyro_noise_rps,
                          "mag_ut": self.model.mag_noise_ut}}


@dataclass(frozen=True)
class CalibrationSession:
    """A phone's calibration state during one survey session (constant within a walk).

    Attributes
    ----------
    session_id : str
        ``"<device_id>-s<index>"``.
    device_id : str
    index : int
        Session number of this phone (0, 1, ...).
    day : int
        Survey day of the session (0 = first day).
    true_hard_iron_ut : tuple of float
        True hard-iron offset (uT, device frame).
    reported_bias_ut : tuple of float
        Bias the phone reports in the uncalibrated stream (uT): true + residual.
    gyro_bias_rps, gyro_bias_reported_rps : tuple of float
        True gyroscope bias and the phone's estimate (rad/s).
    """

    session_id: str
    device_id: str
    index: int
    day: int
    true_hard_iron_ut: tuple[float, float, float]
    reported_bias_ut: tuple[float, float, float]
    gyro_bias_rps: tuple[float, float, float]
    gyro_bias_reported_rps: tuple[float, float, float]

    def to_dict(self) -> dict:
        d = asdict(self)
        for k, v in d.items():
            if isinstance(v, tuple):
                d[k] = list(v)
        d["residual_ut"] = (np.asarray(self.reported_bias_ut)
                            - np.asarray(self.true_hard_iron_ut)).tolist()
        return d


def quantize(values: np.ndarray, resolution: float) -> np.ndarray:
    """Round to a multiple of ``resolution`` (no-op for ``resolution <= 0``)."""
    values = np.asarray(values, dtype=np.float64)
    if resolution <= 0:
        return values
    return np.round(values / resolution) * resolution


def make_device(device_id: str, model: DeviceModel, reference: bool,
                rng: np.random.Generator, *, rssi_k_range: tuple[float, float] = (0.8, 1.2),
                rssi_b_range: tuple[float, float] = (-10.0, 5.0),
                soft_iron_sd: float = 0.03) -> Device:
    """A phone with random soft iron, RSSI distortion (identity for the reference) and offset."""
    off = rng.normal(0.0, soft_iron_sd / 2.0, (3, 3))
    s = np.eye(3) + rng.normal(0.0, soft_iron_sd, 3) * np.eye(3) + 0.5 * (off + off.T) * (
        1.0 - np.eye(3))
    s = np.round(s, 6)
    k = 1.0 if reference else round(float(rng.uniform(*rssi_k_range)), 4)
    b = 0.0 if reference else round(float(rng.uniform(*rssi_b_range)), 3)
    acc_off = np.round(rng.normal(0.0, 0.05, 3), 5)
    return Device(device_id, model, reference, tuple(tuple(float(v) for v in row) for row in s),
                  k, b, tuple(float(v) for v in acc_off))


def make_sessions(device: Device, days: list[int], rng: np.random.Generator, *,
                  base_sd_ut: tuple[float, float, float] = (40.0, 40.0, 120.0),
                  jump_sd_ut: float = 25.0,
                  residual_sd_ut: tuple[float, float, float] = (1.5, 1.5, 4.0)
                  ) -> list[CalibrationSession]:
    """Calibration sessions of a phone, one per survey day in ``days``.

    The true hard iron is a per-phone offset plus a per-session jump (SD ``jump_sd_ut``); the
    reported bias adds a residual error with SD ``residual_sd_ut`` (uT, x y z) and is quantized
    to the magnetometer's resolution, so calibrated values stay on the sensor's grid.
    """
    res = device.model.mag_resolution
    base = rng.normal(0.0, base_sd_ut)
    out = []
    for i, day in enumerate(days):
        h = np.round(base + rng.normal(0.0, jump_sd_ut, 3), 4)
        rep = quantize(h + rng.normal(0.0, residual_sd_ut), res)
        gb = np.round(rng.normal(0.0, 0.003, 3), 7)
        gb_rep = np.round(gb + rng.normal(0.0, 2e-4, 3), 7)
        out.append(CalibrationSession(
            f"{device.device_id}-s{i}", device.device_id, i, int(day),
            tuple(float(v) for v in h), tuple(float(v) for v in rep),
            tuple(float(v) for v in gb), tuple(float(v) for v in gb_rep)))
    return out


@dataclass(frozen=True)
class MagReadings:
    """Magnetometer output of one walk.

    Attributes
    ----------
    uncalibrated_ut : numpy.ndarray, shape (n, 3)
        Raw readings (device frame, quantized).
    bias_ut : numpy.ndarray, shape (3,)
        The phone's reported hard-iron bias.
    calibrated_ut : numpy.ndarray, shape (n, 3)
        ``uncalibrated - bias``.
    """

    uncalibrated_ut: np.ndarray
    bias_ut: np.ndarray
    calibrated_ut: np.ndarray


def magnetometer(field_earth_ut: np.ndarray, q_true: np.ndarray, device: Device,
                 session: CalibrationSession, rng: np.random.Generator,
                 quantized: bool = True) -> MagReadings:
    """Magnetometer readings: ``raw = S @ (R^T B) + h_true + noise``.

    Parameters
    ----------
    field_earth_ut : numpy.ndarray, shape (n, 3)
        True field (E, N, U) at the phone.
    q_true : numpy.ndarray, shape (n, 4)
        True device-to-earth attitude.
    device : Device
    session : CalibrationSession
    rng : numpy.random.Generator
    quantized : bool
        Round to the sensor's resolution.
    """
    b_dev = rot.rotate_inverse(q_true, field_earth_ut)
    s = np.asarray(device.soft_iron)
    raw = b_dev @ s.T + np.asarray(session.true_hard_iron_ut)
    raw = raw + rng.normal(0.0, device.model.mag_noise_ut, raw.shape)
    bias = np.asarray(session.reported_bias_ut, dtype=np.float64)
    if quantized:
        raw = quantize(raw, device.model.mag_resolution)
    return MagReadings(raw, bias, raw - bias)


def accelerometer(specific_force_mps2: np.ndarray, device: Device, rng: np.random.Generator
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(calibrated, uncalibrated, uncalibrated bias columns) accelerometer readings, m/s^2.

    The uncalibrated reading includes the phone's offset; its bias columns are zero, like the
    real phone's. Shapes (n, 3), (n, 3), (3,).
    """
    res = device.model.accel_resolution
    sd = device.model.accel_noise_mps2
    f = np.asarray(specific_force_mps2)
    cal = quantize(f + rng.normal(0.0, sd, f.shape), res)
    uncal = quantize(f + np.asarray(device.accel_offset_mps2) + rng.normal(0.0, sd, f.shape), res)
    return cal, uncal, np.zeros(3)


def gyroscope(rate_rps: np.ndarray, device: Device, session: CalibrationSession,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(calibrated, uncalibrated, reported bias) gyroscope readings, rad/s.

    ``uncal = w + b_true + noise``; ``cal = w + (b_true - b_reported) + noise`` (independent
    noise). Shapes (n, 3), (n, 3), (3,).
    """
    res = device.model.gyro_resolution
    sd = device.model.gyro_noise_rps
    w = np.asarray(rate_rps)
    b_true = np.asarray(session.gyro_bias_rps)
    b_rep = np.asarray(session.gyro_bias_reported_rps)
    uncal = quantize(w + b_true + rng.normal(0.0, sd, w.shape), res)
    cal = quantize(w + (b_true - b_rep) + rng.normal(0.0, sd, w.shape), res)
    return cal, uncal, b_rep


def distort_rssi(rssi_ref_dbm: np.ndarray, device: Device) -> np.ndarray:
    """The phone's RSSI for a reference-phone RSSI: ``k * rssi_ref + b`` (dBm, not rounded)."""
    return device.rssi_k * np.asarray(rssi_ref_dbm, dtype=np.float64) + device.rssi_b
