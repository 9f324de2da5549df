"""Levelling walks before they are merged: per calibration session, a 3-axis hard-iron residual.

Walks of one calibration session share the phone's bias estimate, and with it an error ``r_s``
(uT, device frame). A sample's map-frame field is then ``e = truth + R r_s`` with ``R`` its
attitude. For pairs of samples from different walks at nearly the same place,
``e_i - e_j = R_i r_s(i) - R_j r_s(j) + noise``: linear in the residuals. They are fitted by
robust least squares (soft-L1 loss, so strong local anomalies and position errors do not drag the
fit) with a weak prior that the sample-weighted mean residual is zero (the overall level is
the phones' own, not arbitrary). Walks are not given free offsets of their own: measured on the
real traces, that makes held-out agreement worse (FINDINGS).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy import sparse
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from survey.rotation import rotation_matrices


@dataclass(frozen=True)
class LevellingParams:
    """Parameters of :func:`fit_session_residuals` (metres, uT)."""

    pair_radius_m: float = 0.5
    max_pairs_per_sample: int = 2
    loss_scale_ut: float = 2.0
    anchor_weight: float = 10.0
    min_pairs: int = 30
    subsample: int = 5  # use every n-th sample (50 Hz is far denser than the field varies)


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


def fit_session_residuals(samples: pd.DataFrame, params: LevellingParams = LevellingParams()
                          ) -> pd.DataFrame:
    """Per-session hard-iron residual (device frame, uT).

    Parameters
    ----------
    samples : DataFrame
        Processed samples with ``session``, ``trace_id``, ``x_m``, ``y_m``, ``mag_east_ut``,
        ``mag_north_ut``, ``mag_up_ut`` and the attitude quaternion ``q_w..q_z``.

    Returns
    -------
    DataFrame indexed by session: ``r_x_ut, r_y_ut, r_z_ut``, ``n_pairs``, ``n_samples``.
    Sessions without cross-walk pairs get zero.
    """
    s = samples.iloc[::params.subsample].reset_index(drop=True)
    sessions = np.asarray(sorted(s["session"].unique()))
    sid = np.searchsorted(sessions, s["session"].to_numpy())
    walk = pd.factorize(s["trace_id"])[0]
    i, j = cross_walk_pairs(s["x_m"].to_numpy(), s["y_m"].to_numpy(), walk,
                            params.pair_radius_m, params.max_pairs_per_sample)
    keep = sid[i] != sid[j]  # pairs within one session carry no information on its residual
    i, j = i[keep], j[keep]
    n_sess = len(sessions)
    out = pd.DataFrame(0.0, index=pd.Index(sessions, name="session"),
                       columns=["r_x_ut", "r_y_ut", "r_z_ut"])
    out["n_samples"] = np.bincount(sid, minlength=n_sess)
    pairs_per = np.bincount(np.concatenate([sid[i], sid[j]]), minlength=n_sess)
    out["n_pairs"] = pairs_per
    if len(i) < params.min_pairs or n_sess < 2:
        return out
    r_mat = _rotations(s)
    e = s[["mag_east_ut", "mag_north_ut", "mag_up_ut"]].to_numpy(np.float64)
    d = (e[i] - e[j]).ravel()  # (3p,)
    weights = out["n_samples"].to_numpy(np.float64)
    weights = weights / weights.sum()
    # The model is linear: d = A theta, theta = session residuals stacked (3 per session).
    p = len(i)
    rows = np.repeat(np.arange(3 * p), 3)
    a_i = r_mat[i].reshape(-1)  # (p, a, b) row-major: row p*3+a, column sid*3+b
    a_j = r_mat[j].reshape(-1)
    cols_i = (sid[i][:, None, None] * 3 + np.arange(3)[None, None, :]).repeat(3, axis=1)
    cols_j = (sid[j][:, None, None] * 3 + np.arange(3)[None, None, :]).repeat(3, axis=1)
    anchor_scale = params.anchor_weight * np.sqrt(p)
    anchor = sparse.kron(sparse.csr_matrix(weights[None, :]), sparse.eye(3)) * anchor_scale
    a_mat = sparse.vstack([
        sparse.csr_matrix((a_i, (rows, cols_i.ravel())), shape=(3 * p, 3 * n_sess))
        - sparse.csr_matrix((a_j, (rows, cols_j.ravel())), shape=(3 * p, 3 * n_sess)),
        anchor]).tocsr()
    target = np.concatenate([d, np.zeros(3)])
    fit = least_squares(lambda th: a_mat @ th - target, np.zeros(3 * n_sess),
                        jac=lambda th: a_mat, loss="soft_l1", f_scale=params.loss_scale_ut,
                        method="trf", tr_solver="lsmr")
    r = fit.x.reshape(n_sess, 3)
    out[["r_x_ut", "r_y_ut", "r_z_ut"]] = r * (pairs_per[:, None] > 0)
    return out


def apply_session_residuals(samples: pd.DataFrame, residuals: pd.DataFrame) -> NDArray:
    """Map-frame field (n, 3) with each sample's session residual removed (``e - R r_s``)."""
    r = residuals.reindex(samples["session"])[["r_x_ut", "r_y_ut", "r_z_ut"]].fillna(0.0)
    rot = _rotations(samples)
    e = samples[["mag_east_ut", "mag_north_ut", "mag_up_ut"]].to_numpy(np.float64)
    return e - np.einsum("nab,nb->na", rot, r.to_numpy(np.float64))
