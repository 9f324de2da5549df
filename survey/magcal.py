"""Magnetometer hard- and soft-iron calibration with a coverage and conditioning check.

Model (paper 004: hard-iron offset, unequal axis sensitivity, non-orthogonality; NOTES.md)::

    raw = S @ b + h + noise,        |b| = B (the local field strength)

with ``h`` the hard-iron offset (uT) and ``S`` the symmetric soft-iron matrix. The raw samples of
a phone turned through many orientations lie on the ellipsoid ``(m - h)^T M (m - h) = 1`` with
``M = S^-1 S^-T / B^2``. :func:`fit_ellipsoid` fits the general quadric by least squares
(homogeneous, smallest singular vector), takes the centre as ``h`` and ``S = M^(-1/2)``
normalized to unit determinant, so that the calibrated strength ``|S^-1 (m - h)|`` averages the
geometric-mean radius ``B`` (only ``S * B`` is observable; pass ``reference_strength_ut`` when the
true strength is known). A geometric refinement then minimizes ``| |W (m - h)| - 1 |``.

The fit needs samples from many orientations. Samples of a phone held flat (the ILC surveys:
tilt within ~7 deg) lie close to one horizontal circle; every quadric containing that circle fits
them, so the centre's vertical coordinate is arbitrary -- a sphere fit on such a walk put the
vertical offset ~26 uT off with a deceptively small standard error (``/work/shared/ilc``
FINDINGS). Both fits therefore report

* ``coverage``: ``sqrt(lambda_min / lambda_max)`` of the covariance of the raw samples -- 1 for
  samples spread evenly over a sphere, ~0.1 for a flat-held phone;
* ``condition_number``: of the fit's design matrix (data centred and scaled to unit radius),
  the largest singular value over the smallest one that the solution depends on;
* (ellipsoid) the standard error of the hard iron from the refined fit's Jacobian;

and return ``status="ill-conditioned"`` with a reason (and NaN estimates for the ellipsoid)
instead of a wrong offset.

:func:`fit_with_rotation` is the alternative for flat-held phones: with the rotation vector
known, the earth-frame field at one spot is the same for every heading, so
``raw_i = R_i^T b_earth + h`` is linear in ``(b_earth, h)``. Yaw-only rotation still leaves
``h_up`` and ``b_up`` inseparable; a known vertical component (``reference_vertical_ut``, e.g.
from a calibrated survey or a geomagnetic model) resolves it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize

from survey.errors import ProcessingError

__all__ = [
    "STATUS_ILL",
    "STATUS_OK",
    "MagCalResult",
    "fit_ellipsoid",
    "fit_sphere",
    "fit_with_rotation",
    "sample_coverage",
]

STATUS_OK = "ok"
STATUS_ILL = "ill-conditioned"

_NAN3 = np.full(3, np.nan)


@dataclass(frozen=True)
class MagCalResult:
    """Outcome of a magnetometer calibration fit.

    Attributes
    ----------
    status : str
        ``"ok"`` or ``"ill-conditioned"``.
    method : str
        ``"ellipsoid"``, ``"sphere"`` or ``"rotation"``.
    hard_iron_ut : ndarray, shape (3,)
        Offset ``h`` (uT, device frame). NaN for an ill-conditioned ellipsoid fit.
    soft_iron : ndarray, shape (3, 3)
        Symmetric ``S`` with ``raw = S @ b + h``; unit determinant unless a reference strength
        was given; identity for the sphere and rotation fits.
    field_strength_ut : float
        Strength ``B`` of the calibrated field (geometric-mean radius of the ellipsoid, sphere
        radius, or ``|b_earth|``).
    residual_rms_ut : float
        RMS of ``|S^-1 (raw - h)| - B`` (ellipsoid, sphere) or of the vector residual (rotation).
    condition_number : float
        Condition number of the fit's design (see module docstring).
    coverage : float
        ``sqrt(lambda_min / lambda_max)`` of the raw-sample covariance, in [0, 1].
    reason : str
        Why the status is ill-conditioned ("" when ok).
    n_samples : int
        Samples used.
    hard_iron_se_ut : ndarray, shape (3,)
        Standard error of ``h`` from the fit's Jacobian (uT). Small values do not prove a good
        fit when the coverage is poor.
    earth_field_ut : ndarray, shape (3,)
        Fitted earth-frame field (east, north, up; uT) for the rotation fit, NaN otherwise.
    """

    status: str
    method: str
    hard_iron_ut: NDArray[np.float64]
    soft_iron: NDArray[np.float64]
    field_strength_ut: float
    residual_rms_ut: float
    condition_number: float
    coverage: float
    reason: str
    n_samples: int
    hard_iron_se_ut: NDArray[np.float64]
    earth_field_ut: NDArray[np.float64]

    @property
    def ok(self) -> bool:
        """True when the status is ``"ok"``."""
        return self.status == STATUS_OK

    @property
    def correction(self) -> NDArray[np.float64]:
        """``S^-1``, shape (3, 3): calibrated = ``correction @ (raw - hard_iron)``."""
        return np.linalg.inv(self.soft_iron)

    def apply(self, raw_ut: ArrayLike) -> NDArray[np.float64]:
        """Calibrate raw samples.

        Parameters
        ----------
        raw_ut : array_like, shape (n, 3)
            Raw (uncalibrated) device-frame field (uT).

        Returns
        -------
        ndarray, shape (n, 3)
            ``S^-1 (raw - h)`` (uT); NaN when the fit is ill-conditioned without estimates.
        """
        m = _samples(raw_ut, min_rows=0)
        return (m - self.hard_iron_ut) @ self.correction.T


def _samples(raw_ut: ArrayLike, min_rows: int) -> NDArray[np.float64]:
    m = np.asarray(raw_ut, dtype=np.float64)
    if m.ndim != 2 or m.shape[1] != 3:
        raise ProcessingError(f"magnetometer samples must have shape (n, 3), got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ProcessingError("magnetometer samples contain NaN/inf")
    if len(m) < min_rows:
        raise ProcessingError(f"need at least {min_rows} magnetometer samples, got {len(m)}")
    return m


def sample_coverage(raw_ut: ArrayLike) -> float:
    """Orientation coverage of raw magnetometer samples.

    Parameters
    ----------
    raw_ut : array_like, shape (n, 3)
        Raw device-frame field samples (uT).

    Returns
    -------
    float
        ``sqrt(lambda_min / lambda_max)`` of the sample covariance, in [0, 1]: about 1 for
        orientations spread over the whole sphere, about ``sin(tilt)`` for a phone kept within
        ``tilt`` of one plane, 0 for a single orientation.
    """
    m = _samples(raw_ut, min_rows=2)
    lam = np.linalg.eigvalsh(np.cov(m.T))
    if lam[-1] <= 0:
        return 0.0
    return float(np.sqrt(max(lam[0], 0.0) / lam[-1]))


def _normalize(m: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Centre on the sample mean and scale to unit RMS radius (numerical conditioning)."""
    mu = m.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((m - mu) ** 2, axis=1))))
    if scale <= 0:
        raise ProcessingError("magnetometer samples are all identical")
    return (m - mu) / scale, mu, scale


def _ill(method: str, reason: str, n: int, coverage: float, cond: float,
         hard: NDArray[np.float64] = _NAN3, strength: float = float("nan"),
         rms: float = float("nan"), se: NDArray[np.float64] = _NAN3,
         soft: NDArray[np.float64] | None = None,
         earth: NDArray[np.float64] = _NAN3) -> MagCalResult:
    return MagCalResult(status=STATUS_ILL, method=method, hard_iron_ut=np.array(hard, float),
                        soft_iron=np.full((3, 3), np.nan) if soft is None else soft,
                        field_strength_ut=float(strength), residual_rms_ut=float(rms),
                        condition_number=float(cond), coverage=float(coverage), reason=reason,
                        n_samples=n, hard_iron_se_ut=np.array(se, float),
                        earth_field_ut=np.array(earth, float))


def _sym(p: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])


def _sqrtm_spd(a: NDArray[np.float64], power: float) -> NDArray[np.float64]:
    lam, v = np.linalg.eigh(a)
    return (v * lam ** power) @ v.T


def fit_ellipsoid(raw_ut: ArrayLike, *, reference_strength_ut: float | None = None,
                  min_coverage: float = 0.45, max_condition: float = 15.0,
                  max_hard_iron_se_ut: float = 1.0, refine: bool = True) -> MagCalResult:
    """Hard- and soft-iron calibration by an ellipsoid fit of pooled raw samples.

    Parameters
    ----------
    raw_ut : array_like, shape (n, 3)
        Raw (uncalibrated) magnetometer samples (uT, device frame), pooled over a calibration
        session (one hard iron); n >= 20.
    reference_strength_ut : float, optional
        Known field strength (uT). Without it ``S`` has unit determinant and
        ``field_strength_ut`` is the ellipsoid's geometric-mean radius.
    min_coverage : float
        Minimum :func:`sample_coverage` for an "ok" status.
    max_condition : float
        Maximum condition number of the quadric design for an "ok" status: largest singular
        value over the second smallest (the smallest belongs to the solution) of the design
        ``[x^2, y^2, z^2, 2yz, 2xz, 2xy, 2x, 2y, 2z, 1]`` of the data centred and scaled to unit
        radius. Simulated 45 uT field, 0.5 uT noise: about 3.5 for orientations over the whole
        sphere, 10 for tilts up to 45 deg, 20 for 30 deg, 70 for a flat-held phone or for
        rotations about two axes only.
    max_hard_iron_se_ut : float
        Maximum standard error (uT) of any hard-iron component for an "ok" status. The standard
        error underestimates the error of a marginal fit (bias), hence the other two checks.
    refine : bool
        Refine the algebraic fit by minimizing the radial residual ``|W (m - h)| - 1`` over
        ``h`` and symmetric ``W`` (Levenberg-Marquardt / TRF).

    Returns
    -------
    MagCalResult
        ``method="ellipsoid"``. Ill-conditioned results carry NaN for ``hard_iron_ut`` and
        ``soft_iron`` and say why in ``reason``. Default thresholds: on simulated data (45 uT,
        0.5 uT noise, +-5 % soft iron) an "ok" fit had hard-iron errors below 1.4 uT (tilt
        range 45 deg) and below 0.1 uT with full coverage.

    Raises
    ------
    ProcessingError
        Bad shape, non-finite values or fewer than 20 samples.
    """
    m = _samples(raw_ut, min_rows=20)
    n = len(m)
    cov = sample_coverage(m)
    x, mu, scale = _normalize(m)
    x1, x2, x3 = x.T
    d = np.column_stack([x1 * x1, x2 * x2, x3 * x3, 2 * x2 * x3, 2 * x1 * x3, 2 * x1 * x2,
                         2 * x1, 2 * x2, 2 * x3, np.ones(n)])
    _, sv, vt = np.linalg.svd(d, full_matrices=False)
    cond = float(sv[0] / sv[-2]) if sv[-2] > 0 else float("inf")
    if cov < min_coverage:
        return _ill("ellipsoid", f"orientation coverage {cov:.3f} < {min_coverage} (samples lie "
                    "close to a plane: rotate the phone through all axes)", n, cov, cond)
    if cond > max_condition:
        return _ill("ellipsoid", f"design condition number {cond:.3g} > {max_condition:.3g}",
                    n, cov, cond)
    v = vt[-1]
    a = _sym(v[[0, 1, 2, 5, 4, 3]])  # (xx, yy, zz, xy, xz, yz)
    if np.trace(a) < 0:
        a, v = -a, -v
    lam = np.linalg.eigvalsh(a)
    if lam[0] <= 0:
        return _ill("ellipsoid", "fitted quadric is not an ellipsoid", n, cov, cond)
    c = -np.linalg.solve(a, v[6:9])
    k = c @ a @ c - v[9]
    if k <= 0:
        return _ill("ellipsoid", "fitted quadric is empty", n, cov, cond)
    w = _sqrtm_spd(a / k, 0.5)          # maps (x - c) to the unit sphere, normalized units
    params = np.concatenate([w[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]], c])

    def resid(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.linalg.norm((x - p[6:]) @ _sym(p[:6]), axis=1) - 1.0

    if refine:
        sol = optimize.least_squares(resid, params, method="lm", x_scale="jac", max_nfev=200)
        params = sol.x
    r = resid(params)
    w = _sym(params[:6])
    lam_w = np.linalg.eigvalsh(w)
    if lam_w[0] <= 0:
        return _ill("ellipsoid", "refined fit is not an ellipsoid", n, cov, cond)
    hard = mu + scale * params[6:]
    w_ut = w / scale                                  # W in 1/uT: |W_ut (m - h)| = 1
    s_b = np.linalg.inv(w_ut)                         # = S * B
    strength = float(np.cbrt(np.linalg.det(s_b)))
    soft = s_b / (reference_strength_ut if reference_strength_ut else strength)
    field_b = reference_strength_ut if reference_strength_ut else strength
    rms = float(field_b * np.sqrt(np.mean(r ** 2)))
    se = _hard_iron_se(resid, params, r, scale)
    if not np.all(se <= max_hard_iron_se_ut):
        return _ill("ellipsoid", f"hard-iron standard error {np.max(se):.3g} uT > "
                    f"{max_hard_iron_se_ut} uT", n, cov, cond, se=se)
    return MagCalResult(status=STATUS_OK, method="ellipsoid", hard_iron_ut=hard, soft_iron=soft,
                        field_strength_ut=float(field_b), residual_rms_ut=rms,
                        condition_number=cond, coverage=cov, reason="", n_samples=n,
                        hard_iron_se_ut=se, earth_field_ut=_NAN3.copy())


def _hard_iron_se(fun, params: NDArray[np.float64], r: NDArray[np.float64],
                  scale: float) -> NDArray[np.float64]:
    """Standard error of the last three parameters (the centre), in uT."""
    eps = 1e-7
    jac = np.empty((len(r), len(params)))
    for j in range(len(params)):
        dp = np.zeros_like(params)
        dp[j] = eps
        jac[:, j] = (fun(params + dp) - fun(params - dp)) / (2 * eps)
    dof = max(len(r) - len(params), 1)
    s2 = float(r @ r) / dof
    try:
        covp = np.linalg.inv(jac.T @ jac) * s2
    except np.linalg.LinAlgError:
        return np.full(3, np.inf)
    return scale * np.sqrt(np.clip(np.diag(covp)[-3:], 0.0, None))


def fit_sphere(raw_ut: ArrayLike, *, min_coverage: float = 0.45,
               max_condition: float = 5.0) -> MagCalResult:
    """Hard-iron-only baseline: least-squares sphere fit of one walk's raw samples.

    Solves ``|m|^2 = 2 c . m + (r^2 - |c|^2)`` linearly. Unlike :func:`fit_ellipsoid` the
    estimates are always returned (it is a baseline), but the status still flags poor
    coverage: on a flat-held phone the centre's vertical coordinate is not determined.

    Parameters
    ----------
    raw_ut : array_like, shape (n, 3)
        Raw magnetometer samples (uT); n >= 4.
    min_coverage : float
        Minimum :func:`sample_coverage` for an "ok" status.
    max_condition : float
        Maximum condition number of the (centred, unit-radius) design ``[2x, 2y, 2z, 1]``
        (about 1.2 for full coverage, 3 for tilts up to 30 deg, 10 or more for a flat phone).

    Returns
    -------
    MagCalResult
        ``method="sphere"``, ``soft_iron`` the identity.
    """
    m = _samples(raw_ut, min_rows=4)
    n = len(m)
    cov = sample_coverage(m)
    x, mu, scale = _normalize(m)
    d = np.column_stack([2 * x, np.ones(n)])
    sv = np.linalg.svd(d, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    sol, *_ = np.linalg.lstsq(d, np.sum(x * x, axis=1), rcond=None)
    c = sol[:3]
    r2 = sol[3] + c @ c
    radius = float(np.sqrt(max(r2, 0.0)))
    resid = np.linalg.norm(x - c, axis=1) - radius
    dof = max(n - 4, 1)
    s2 = float(np.sum((np.sum(x * x, axis=1) - d @ sol) ** 2)) / dof
    try:
        covp = np.linalg.inv(d.T @ d) * s2
        se = scale * np.sqrt(np.clip(np.diag(covp)[:3], 0.0, None))
    except np.linalg.LinAlgError:
        se = np.full(3, np.inf)
    hard = mu + scale * c
    reasons = []
    if cov < min_coverage:
        reasons.append(f"orientation coverage {cov:.3f} < {min_coverage}")
    if cond > max_condition:
        reasons.append(f"design condition number {cond:.3g} > {max_condition:.3g}")
    return MagCalResult(status=STATUS_ILL if reasons else STATUS_OK, method="sphere",
                        hard_iron_ut=hard, soft_iron=np.eye(3),
                        field_strength_ut=radius * scale,
                        residual_rms_ut=float(scale * np.sqrt(np.mean(resid ** 2))),
                        condition_number=cond, coverage=cov, reason="; ".join(reasons),
                        n_samples=n, hard_iron_se_ut=se, earth_field_ut=_NAN3.copy())


def fit_with_rotation(raw_ut: ArrayLike, rot_device_to_earth: ArrayLike, *,
                      reference_vertical_ut: float | None = None,
                      max_condition: float = 10.0,
                      max_residual_rms_ut: float = 3.0) -> MagCalResult:
    """Hard iron from samples at one spot with known attitude (field constant in the earth frame).

    Solves ``raw_i = R_i^T b + h`` for ``h`` (device frame) and the earth-frame field ``b`` by
    linear least squares; the samples must come from a small area (the field varies by several
    uT over a metre indoors) and the soft iron is taken as identity (apply an ellipsoid
    correction first when known).

    Parameters
    ----------
    raw_ut : array_like, shape (n, 3)
        Raw magnetometer samples (uT, device frame).
    rot_device_to_earth : array_like, shape (n, 3, 3)
        Device-to-earth (ENU) rotation per sample, from :func:`survey.rotation.rotation_matrices`.
    reference_vertical_ut : float, optional
        Known up component of the earth field (uT, up positive). Fixes ``b_up`` so that yaw-only
        rotation (flat-held phone) determines all of ``h``.
    max_condition : float
        Maximum condition number of the column-scaled design for an "ok" status. Full rotation
        gives about 1.1; a phone tilted at most 7 deg about 23 (exact in simulation, but the
        vertical offset then rests on the small tilts and amplifies rotation-vector errors);
        yaw only without ``reference_vertical_ut`` is singular.
    max_residual_rms_ut : float
        Maximum RMS (uT) of the vector residual ``|raw_i - R_i^T b - h|`` for an "ok" status; a
        larger one means the field was not constant over the samples (they come from more than
        one spot, e.g. a whole walk: 2-11 uT on the ILC walks) or the rotations are off.

    Returns
    -------
    MagCalResult
        ``method="rotation"``, ``earth_field_ut`` the fitted ``b``; estimates are returned even
        when ill-conditioned (the status says whether to trust them).
    """
    m = _samples(raw_ut, min_rows=3)
    r = np.asarray(rot_device_to_earth, dtype=np.float64)
    if r.shape != (len(m), 3, 3) or not np.all(np.isfinite(r)):
        raise ProcessingError(f"rotations must have shape ({len(m)}, 3, 3) and be finite")
    n = len(m)
    cov = sample_coverage(m)
    rt = np.transpose(r, (0, 2, 1))                   # earth -> device
    eye = np.broadcast_to(np.eye(3), (n, 3, 3))
    design = np.concatenate([rt, eye], axis=2).reshape(3 * n, 6)
    target = m.reshape(3 * n)
    cols = [0, 1, 2, 3, 4, 5]
    if reference_vertical_ut is not None:
        target = target - rt[:, :, 2].reshape(3 * n) * reference_vertical_ut
        cols = [0, 1, 3, 4, 5]
    a = design[:, cols]
    norms = np.linalg.norm(a, axis=0)
    norms[norms == 0] = 1.0
    sv = np.linalg.svd(a / norms, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    sol, *_ = np.linalg.lstsq(a, target, rcond=None)
    full = np.zeros(6)
    full[cols] = sol
    if reference_vertical_ut is not None:
        full[2] = reference_vertical_ut
    resid = target - a @ sol
    dof = max(3 * n - len(cols), 1)
    s2 = float(resid @ resid) / dof
    se = np.full(3, np.inf)
    if cond < 1e12:
        covp = np.linalg.inv(a.T @ a) * s2
        se = np.sqrt(np.clip(np.diag(covp)[-3:], 0.0, None))
    b, h = full[:3], full[3:]
    rms = float(np.sqrt(np.mean(np.sum(resid.reshape(n, 3) ** 2, axis=1))))
    reason = ""
    if cond > max_condition:
        reason = (f"design condition number {cond:.3g} > {max_condition:.3g} (rotation about "
                  "one axis only: give reference_vertical_ut)")
    elif rms > max_residual_rms_ut:
        reason = (f"residual RMS {rms:.3g} uT > {max_residual_rms_ut} uT (field not constant "
                  "over the samples)")
    if reason:
        return _ill("rotation", reason, n, cov, cond, hard=h, strength=float(np.linalg.norm(b)),
                    rms=rms, se=se, soft=np.eye(3), earth=b)
    return MagCalResult(status=STATUS_OK, method="rotation", hard_iron_ut=h, soft_iron=np.eye(3),
                        field_strength_ut=float(np.linalg.norm(b)), residual_rms_ut=rms,
                        condition_number=cond, coverage=cov, reason="", n_samples=n,
                        hard_iron_se_ut=se, earth_field_ut=b)
