"""Smooth random processes and ramps used by the walker, the IMU and the radio models."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d


def smooth_noise(n: int, sigma_samples: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian-filtered white noise with unit (theoretical) standard deviation.

    Parameters
    ----------
    n : int
        Number of samples.
    sigma_samples : float
        Standard deviation of the Gaussian kernel, in samples (the correlation length).
    rng : numpy.random.Generator

    Returns
    -------
    numpy.ndarray, shape (n,)
        Zero-mean process whose standard deviation is 1 in expectation.
    """
    white = rng.standard_normal(n)
    if sigma_samples <= 0.3:
        return white
    pad = int(4 * sigma_samples) + 1
    white = np.concatenate([rng.standard_normal(pad), white, rng.standard_normal(pad)])
    out = gaussian_filter1d(white, sigma_samples, mode="reflect")[pad:pad + n]
    # variance of white noise filtered by a unit-sum Gaussian kernel: 1 / (2 sqrt(pi) sigma)
    return out * np.sqrt(2.0 * np.sqrt(np.pi) * sigma_samples)


def raised_cosine_ramp(x: np.ndarray, width: float) -> np.ndarray:
    """0 for ``x <= 0``, 1 for ``x >= width``, a raised-cosine rise in between.

    Parameters
    ----------
    x : numpy.ndarray
        Positions (any unit, same as ``width``).
    width : float
        Length of the rise; ``0`` gives a step.
    """
    x = np.asarray(x, dtype=np.float64)
    if width <= 0:
        return (x >= 0).astype(np.float64)
    u = np.clip(x / width, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * u)


def wrap_deg(angle_deg: np.ndarray | float) -> np.ndarray:
    """Wrap angles to [-180, 180) degrees."""
    return (np.asarray(angle_deg, dtype=np.float64) + 180.0) % 360.0 - 180.0
