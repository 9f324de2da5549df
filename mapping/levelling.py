"""Levelling walks before they are merged: per calibration session a 3-axis hard-iron residual,
per phone model a soft-iron correction.

Walks of one calibration session share the phone's bias estimate, and with it an error ``r_s``
(uT, device frame). A phone model also scales and skews the field a little (soft iron,
``m = (I + D) b + r_s`` with ``D`` symmetric, a few per cent; paper and simulator alike). With
``R`` the sample's attitude, the measured map-frame field is, to first order,
``e = truth + R (D m + r_s)`` with ``m = R^T e`` the device-frame reading. For pairs of samples
from different walks at nearly the same place, ``e_i - e_j`` is linear in the residuals and the
soft-iron entries. They are fitted by robust least squares (soft-L1 loss, so strong local
anomalies and position errors do not drag the fit) with weak priors: the sample-weighted mean
residual is zero and so is the sample-weighted mean isotropic scale (the overall level is the
phones' own, not arbitrary), and every soft-iron entry is shrunk towards zero.

A soft-iron matrix is only fitted when the floor has walks of at least two phone models: a phone
is scaled relative to another one; with a single model its isotropic and vertical scale are
unobservable for a flat phone and the fit absorbs position errors instead (measured on the real
traces, one model: held-out strength skill on site1/F1 fell from 0.143 to 0.113). Walks are not
given free offsets of their own: measured on the real traces, that makes held-out agreement worse
(FINDINGS).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy import sparse
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from survey.process import session_device
from survey.rotation import rotation_matrices

#: Columns of the fitted soft-iron correction ``D`` (symmetric, dimensionless).
SOFT_IRON_COLUMNS = ("s_xx", "s_yy", "s_zz", "s_xy", "s_xz", "s_yz")
RESIDUAL_COLUMNS = ("r_x_ut", "r_y_ut", "r_z_ut")
SOFT_IRON_MODES = ("auto", "on", "off")


@dataclass(frozen=True)
class LevellingParams:
    """Parameters of :func:`fit_session_residuals` (metres, uT)."""

    pair_radius_m: float = 0.5
    max_pairs_per_sample: int = 2
    loss_scale_ut: float = 2.0
    anchor_weight: float = 10.0
    min_pairs: int = 30
    subsample: int = 5  # use every n-th sample (50 Hz is far denser than the field varies)
    #: fit a soft-iron matrix per phone model: "auto" (when the floor has two models or more),
    #: "on" or "off"
    soft_iron: str = "auto"
    #: weight of the prior that every soft-iron entry is zero (relative to the pairs)
    soft_iron_prior: float = 1.0

    def __post_init__(self) -> None:
        if self.soft_iron not in SOFT_IRON_MODES:
            raise ValueError(f"levelling soft_iron must be one of {SOFT_IRON_MODES}, "
                             f"got {self.soft_iron!r}")
        if not self.soft_iron_prior >= 0:
            raise ValueError(f"levelling soft_iron_prior must be >= 0, got "
                             f"{self.soft_iron_prior!r}")


def cross_walk_pairs(x_m: NDArray, y_m: NDArray, walk: NDArray, radius_m: float,
                     max_per_sample: int = 2) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Index pairs (i < j) of samples from different walks within ``radius_m``."""
    xy = np.column_stack([x_m, y_m])
    tree = cKDTree(xy)
    k = min(len(xy), 8 * max_per_sample + 1)
    d, j = tree.query(xy, k=k, distance_upper_bound=radius_m)
    i_idx, j_idx = [], []
    taken = np.zeros(len(xy), dtype=np.int64)
    for col in range(1, k):
        ok = np.isfinite(d[:, col])
        jj = np.where(ok, j[:, col], 0)
        sel = ok & (walk[jj] != walk) & (taken < max_per_sample) & (np.arange(len(xy)) < jj)
        i_idx.append(np.flatnonzero(sel))
        j_idx.append(jj[sel])
        taken[sel] += 1
    return np.concatenate(i_idx), np.concatenate(j_idx)


def _rotations(samples: pd.DataFrame) -> NDArray[np.float64]:
    q = samples[["q_w", "q_x", "q_y", "q_z"]].to_numpy(np.float64)
    return rotation_matrices(q, quaternion=True)


def empty_residuals() -> pd.DataFrame:
    """A levelling table without sessions (what an unlevelled build stores)."""
    return pd.DataFrame({**{c: pd.Series(dtype=np.float64)
                            for c in (*RESIDUAL_COLUMNS, *SOFT_IRON_COLUMNS)},
                         "device": pd.Series(dtype=str), "n_samples": pd.Series(dtype=np.int64),
                         "n_pairs": pd.Series(dtype=np.int64)}, index=pd.Index([], name="session"))


def soft_iron_design(m_ut: NDArray[np.float64]) -> NDArray[np.float64]:
    """``D m`` as a linear map of ``D``'s entries (:data:`SOFT_IRON_COLUMNS`): (n, 3) device-frame
    readings (uT) -> (n, 3, 6)."""
    m = np.asarray(m_ut, dtype=np.float64)
    z = np.zeros(len(m))
    mx, my, mz = m.T
    return np.stack([np.stack([mx, z, z, my, mz, z], axis=1),
                     np.stack([z, my, z, mx, z, mz], axis=1),
                     np.stack([z, z, mz, z, mx, my], axis=1)], axis=1)


def _pair_design(r_mat: NDArray, m: NDArray, idx: NDArray, sid: NDArray, did: NDArray | None,
                 n_cols: int, n_sess: int) -> sparse.csr_matrix:
    """Rows ``3 p + a`` of ``R (D m + r_s)`` for the samples ``idx`` (one per pair)."""
    p = len(idx)
    rows = np.repeat(np.arange(3 * p), 3)
    cols = (sid[idx][:, None, None] * 3 + np.arange(3)[None, None, :]).repeat(3, axis=1)
    a = sparse.csr_matrix((r_mat[idx].reshape(-1), (rows, cols.ravel())), shape=(3 * p, n_cols))
    if did is not None:
        g = np.einsum("nab,nbc->nac", r_mat[idx], soft_iron_design(m[idx]))  # (p, 3, 6)
        rows6 = np.repeat(np.arange(3 * p), 6)
        cols6 = (3 * n_sess + did[idx][:, None, None] * 6
                 + np.arange(6)[None, None, :]).repeat(3, axis=1)
        a = a + sparse.csr_matrix((g.reshape(-1), (rows6, cols6.ravel())), shape=(3 * p, n_cols))
    return a


def fit_session_residuals(samples: pd.DataFrame, params: LevellingParams = LevellingParams()
                          ) -> pd.DataFrame:
    """Per-session hard-iron residual (device frame, uT) and per-model soft-iron correction.

    Parameters
    ----------
    samples : DataFrame
        Processed samples with ``session`` (keys of :func:`survey.process.calibration_sessions`,
        which name the phone model), ``trace_id``, ``x_m``, ``y_m``, ``mag_east_ut``,
        ``mag_north_ut``, ``mag_up_ut`` and the attitude quaternion ``q_w..q_z``.

    Returns
    -------
    DataFrame indexed by session: ``r_x_ut, r_y_ut, r_z_ut``; the soft-iron entries
    :data:`SOFT_IRON_COLUMNS` of the session's phone model (zero when not fitted); ``device``,
    ``n_pairs``, ``n_samples``. Sessions without cross-walk pairs get zero residuals.
    """
    s = samples.iloc[::params.subsample].reset_index(drop=True)
    sessions = np.asarray(sorted(s["session"].astype(str).unique()))
    sid = np.searchsorted(sessions, s["session"].astype(str).to_numpy())
    session_model = [session_device(k) for k in sessions]
    models = sorted(set(session_model))
    fit_soft = params.soft_iron == "on" or (params.soft_iron == "auto" and len(models) >= 2)
    walk = pd.factorize(s["trace_id"])[0]
    i, j = cross_walk_pairs(s["x_m"].to_numpy(), s["y_m"].to_numpy(), walk,
                            params.pair_radius_m, params.max_pairs_per_sample)
    keep = sid[i] != sid[j]  # pairs within one session carry little information on its residual
    i, j = i[keep], j[keep]
    n_sess, n_mod = len(sessions), len(models)
    out = pd.DataFrame(0.0, index=pd.Index(sessions, name="session"),
                       columns=[*RESIDUAL_COLUMNS, *SOFT_IRON_COLUMNS])
    out["device"] = session_model
    out["n_samples"] = np.bincount(sid, minlength=n_sess)
    pairs_per = np.bincount(np.concatenate([sid[i], sid[j]]), minlength=n_sess)
    out["n_pairs"] = pairs_per
    if len(i) < params.min_pairs or n_sess < 2:
        return out
    r_mat = _rotations(s)
    e = s[["mag_east_ut", "mag_north_ut", "mag_up_ut"]].to_numpy(np.float64)
    m = np.einsum("nba,nb->na", r_mat, e)  # device-frame readings
    model_of_session = np.searchsorted(models, session_model)
    did = model_of_session[sid] if fit_soft else None
    n_cols = 3 * n_sess + (6 * n_mod if fit_soft else 0)
    p = len(i)
    design = (_pair_design(r_mat, m, i, sid, did, n_cols, n_sess)
              - _pair_design(r_mat, m, j, sid, did, n_cols, n_sess))
    weights = out["n_samples"].to_numpy(np.float64)
    weights = weights / weights.sum()
    anchor_scale = params.anchor_weight * np.sqrt(p)
    # the overall level is the phones' own: sample-weighted mean residual zero
    priors = [sparse.hstack([sparse.kron(sparse.csr_matrix(weights[None, :]), sparse.eye(3)),
                             sparse.csr_matrix((3, n_cols - 3 * n_sess))]) * anchor_scale]
    if fit_soft:
        strength = float(np.median(np.linalg.norm(e, axis=1)))
        model_weight = np.bincount(model_of_session, weights=weights, minlength=n_mod)
        iso = np.zeros((1, n_cols))  # ... and so is the mean isotropic scale
        for k in range(n_mod):
            iso[0, 3 * n_sess + 6 * k: 3 * n_sess + 6 * k + 3] = model_weight[k] * strength
        priors.append(sparse.csr_matrix(iso) * anchor_scale)
        if params.soft_iron_prior > 0:
            priors.append(sparse.hstack([
                sparse.csr_matrix((6 * n_mod, 3 * n_sess)),
                sparse.eye(6 * n_mod) * params.soft_iron_prior * strength * np.sqrt(p)]))
    a_mat = sparse.vstack([design, *priors]).tocsr()
    target = np.concatenate([(e[i] - e[j]).ravel(), np.zeros(a_mat.shape[0] - 3 * p)])
    # x_scale="jac": the soft-iron entries act through m (~40 uT), the residuals directly; the
    # unscaled trust region took ~50x more iterations when both are fitted
    fit = least_squares(lambda th: a_mat @ th - target, np.zeros(n_cols),
                        jac=lambda th: a_mat, loss="soft_l1", f_scale=params.loss_scale_ut,
                        method="trf", tr_solver="lsmr", x_scale="jac")
    r = fit.x[:3 * n_sess].reshape(n_sess, 3)
    out[list(RESIDUAL_COLUMNS)] = r * (pairs_per[:, None] > 0)
    if fit_soft:
        out[list(SOFT_IRON_COLUMNS)] = fit.x[3 * n_sess:].reshape(n_mod, 6)[model_of_session]
    return out


def apply_session_residuals(samples: pd.DataFrame, residuals: pd.DataFrame) -> NDArray:
    """Map-frame field (n, 3) with each sample's session residual and soft-iron correction
    removed (``e - R (D m + r_s)``, ``m = R^T e``); tables without soft-iron columns (bundles
    from before they existed) apply the residual only."""
    per = residuals.reindex(samples["session"].astype(str))
    rot = _rotations(samples)
    e = samples[["mag_east_ut", "mag_north_ut", "mag_up_ut"]].to_numpy(np.float64)
    corr = per[list(RESIDUAL_COLUMNS)].fillna(0.0).to_numpy(np.float64)
    if all(c in per.columns for c in SOFT_IRON_COLUMNS):
        d = per[list(SOFT_IRON_COLUMNS)].fillna(0.0).to_numpy(np.float64)
        if d.any():
            m = np.einsum("nba,nb->na", rot, e)
            corr = corr + np.einsum("nac,nc->na", soft_iron_design(m), d)
    return e - np.einsum("nab,nb->na", rot, corr)
