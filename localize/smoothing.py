"""Fixed-interval smoothing of a particle filter by genealogy (offline, whole walk).

A filter's estimate at step ``t`` uses the observations up to ``t`` only. When the whole walk is
at hand (post-processing, survey positioning, evaluation), the particles alive at the end carry
the evidence of every later step: tracing each of them back through its ancestors gives a
sample of whole paths that agree with all observations, and the mean of their positions at
``t`` is the smoothed estimate (Kitagawa 1996: the genealogical smoother). With resampling at
every step the early part of the walk descends from few ancestors; that is the method's known
degeneracy, and it still yields the path that survived all the evidence.

Where no lineage reaches back (particles injected around a radio fix or re-drawn after all
died have no ancestor), the smoother restarts from that step's whole particle set: before such
a break the estimate is smoothed only by the evidence up to the break.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["Genealogy"]


class Genealogy:
    """Per-step particle positions and ancestor slots of one user, recorded while filtering.

    Call :meth:`record` once at the start (``parents=None``) and once after every step (after
    resampling), with each particle's ancestor slot in the previous record (-1 = none).
    """

    def __init__(self) -> None:
        self._x: list[NDArray[np.float64]] = []
        self._y: list[NDArray[np.float64]] = []
        self._parents: list[NDArray[np.int64]] = []

    def record(self, x_m: NDArray, y_m: NDArray, parents: NDArray | None) -> None:
        """Positions (m, shape (n,)) of the particles now and their ancestors' slots (n,) in
        the previous record (None for the first record)."""
        x = np.array(x_m, dtype=np.float64).reshape(-1)
        y = np.array(y_m, dtype=np.float64).reshape(-1)
        if len(x) != len(y):
            raise ValueError(f"{len(x)} x but {len(y)} y positions")
        if parents is None:
            par = np.full(len(x), -1, dtype=np.int64)
        else:
            par = np.asarray(parents).astype(np.int64).reshape(-1)
            if len(par) != len(x):
                raise ValueError(f"{len(par)} parents for {len(x)} particles")
            if len(self._x) == 0:
                raise ValueError("the first record has no parents")
            prev = len(self._x[-1])
            if np.any(par >= prev) or np.any(par < -1):
                raise ValueError(f"parents must be -1 or slots of the previous record "
                                 f"(0..{prev - 1})")
        self._x.append(x)
        self._y.append(y)
        self._parents.append(par)

    def smoothed(self, final_weights: NDArray | None = None
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """Smoothed positions of every record, shapes (T,), (T,) (m), and whether each came
        from the final particles' lineages (False: restarted after a lineage break).

        ``final_weights`` (n,): weights of the last record's particles (default equal, as
        right after resampling); each path keeps its final particle's weight. Particles with
        non-finite positions are ignored in the means.
        """
        n_rec = len(self._x)
        sx, sy = np.full(n_rec, np.nan), np.full(n_rec, np.nan)
        traced = np.zeros(n_rec, dtype=bool)
        if n_rec == 0:
            return sx, sy, traced
        n_end = len(self._x[-1])
        w = np.ones(n_end) if final_weights is None else \
            np.asarray(final_weights, dtype=np.float64).reshape(-1)
        if len(w) != n_end or not np.all(np.isfinite(w) & (w >= 0)):
            raise ValueError(f"final_weights must be {n_end} finite non-negative values")
        idx = np.arange(n_end)
        from_end = True
        for t in range(n_rec - 1, -1, -1):
            if len(idx) == 0 or w.sum() <= 0:  # every lineage broke: restart from this step
                idx, from_end = np.arange(len(self._x[t])), False
                w = np.ones(len(idx))
            x, y = self._x[t][idx], self._y[t][idx]
            ok = np.isfinite(x) & np.isfinite(y) & (w > 0)
            if ok.any():
                sx[t] = np.average(x[ok], weights=w[ok])
                sy[t] = np.average(y[ok], weights=w[ok])
            traced[t] = from_end
            par = self._parents[t][idx]
            keep = par >= 0
            idx, w = par[keep], w[keep]
        return sx, sy, traced
