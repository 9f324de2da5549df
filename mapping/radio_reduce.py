"""Building blocks of the walk-by-walk radio build: integer codes of text values, running
per-key aggregates, and deterministic capped samples of walks.

The radio maps are reduced walk by walk (:mod:`mapping.radio_build`): each walk's observation
rows are turned into per-key partial aggregates (per (cell, transmitter), per (transmitter,
walk), ...) at once, so that memory grows with the number of distinct keys (bounded by the
area and the transmitters), not with the rows of the survey.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from .errors import FingerprintError

__all__ = ["IntCodes", "KeyedAggregate", "TextCodes", "capped_walk_sample", "walk_rows"]


class TextCodes:
    """Integer codes of text values, assigned in first-seen order and stable afterwards."""

    def __init__(self) -> None:
        self._code: dict[str, int] = {}

    def __len__(self) -> int:
        return len(self._code)

    def codes(self, values: pd.Series | NDArray) -> NDArray[np.int64]:
        """Code of every value (new values get the next codes; -1 for a missing value); one
        lookup per distinct value, so a categorical column of millions of rows is cheap."""
        idx, uniques = pd.factorize(pd.Series(values))
        lookup = np.array([self._code.setdefault(str(u), len(self._code)) for u in uniques]
                          + [-1], dtype=np.int64)
        return lookup[idx]

    def names(self) -> NDArray[np.str_]:
        """The values in code order."""
        return np.array(list(self._code), dtype=str)

    def sorted_rank(self) -> NDArray[np.int64]:
        """Position of every code's value in the sorted values (code -> rank)."""
        names = self.names()
        rank = np.empty(len(names), dtype=np.int64)
        rank[np.argsort(names, kind="stable")] = np.arange(len(names))
        return rank


class IntCodes:
    """Dense codes of integer values (e.g. cell keys), assigned in order of first addition
    (sorted within one call)."""

    def __init__(self) -> None:
        self._code: dict[int, int] = {}

    def __len__(self) -> int:
        return len(self._code)

    def codes(self, values: NDArray[np.int64]) -> NDArray[np.int64]:
        """Code of every value (new values get the next codes), one lookup per distinct
        value."""
        uniq, inv = np.unique(np.asarray(values, dtype=np.int64), return_inverse=True)
        lookup = np.array([self._code.setdefault(int(u), len(self._code)) for u in uniq],
                          dtype=np.int64)
        return lookup[inv.reshape(-1)]

    def values(self) -> NDArray[np.int64]:
        """The values in code order."""
        return np.fromiter(self._code, dtype=np.int64, count=len(self._code))


class KeyedAggregate:
    """Running sums per int64 key of rows added in batches.

    Added arrays are kept until they hold ``compact_rows`` rows, then reduced to one row per
    distinct key: memory is bounded by the distinct keys plus one batch. Float sums depend on
    the order rows are added in, never on anything else; integer sums are exact (below 2**53).

    Parameters
    ----------
    names : sequence of str
        The summed values.
    """

    def __init__(self, names: Sequence[str], *, compact_rows: int = 1_000_000) -> None:
        self.names = list(names)
        self.compact_rows = int(compact_rows)
        self._keys: list[NDArray[np.int64]] = []
        self._values: dict[str, list[NDArray]] = {v: [] for v in self.names}
        self._pending = 0
        self._reduced = True  # the parts are one part with distinct keys

    def add(self, keys: NDArray[np.int64], **values: NDArray | float) -> None:
        """Add rows: ``keys`` (int64, shape (n,)) and one array (or scalar) per value name."""
        keys = np.asarray(keys, dtype=np.int64).reshape(-1)
        if len(keys) == 0:
            return
        self._keys.append(keys)
        for name in self.names:
            v = np.asarray(values[name])
            self._values[name].append(np.broadcast_to(v, keys.shape).copy() if v.ndim == 0
                                      else v.reshape(-1))
        self._pending += len(keys)
        self._reduced = False
        if self._pending > self.compact_rows:
            self._compact()

    def _compact(self) -> None:
        self._pending = 0
        if not self._keys or self._reduced:
            return
        keys, inv = np.unique(np.concatenate(self._keys), return_inverse=True)
        inv = inv.reshape(-1)
        self._keys = [keys]
        for name in self.names:
            v = np.concatenate(self._values[name])
            out = np.bincount(inv, weights=v, minlength=len(keys))
            self._values[name] = [np.rint(out).astype(np.int64) if v.dtype.kind in "iub"
                                  else out]
        self._reduced = True

    def result(self) -> tuple[NDArray[np.int64], dict[str, NDArray]]:
        """Sorted distinct keys and the sum of each value per key."""
        self._compact()
        if not self._keys:
            return np.zeros(0, np.int64), {n: np.zeros(0) for n in self.names}
        return self._keys[0], {n: v[0] for n, v in self._values.items()}


def capped_walk_sample(sizes: Mapping[str, int] | pd.Series, cap: int, *,
                       seed: int = 0) -> set[str]:
    """Walks (ids) to use when only about ``cap`` rows may be held at once.

    Every walk gets a pseudo-random priority from its id and ``seed`` (sha256: the same walks
    are chosen on every machine and in any reading order); walks are taken by priority until
    their ``sizes`` (rows) reach ``cap`` (the last walk taken may pass it; a walk larger than
    ``cap`` is taken alone). All walks when they fit.
    """
    sizes = pd.Series(sizes, dtype=np.int64)
    if sizes.sum() <= cap:
        return set(map(str, sizes.index))
    prio = [hashlib.sha256(f"{seed}:{w}".encode()).hexdigest() for w in sizes.index]
    ordered = sizes.iloc[np.argsort(np.array(prio), kind="stable")]
    before = ordered.cumsum().to_numpy() - ordered.to_numpy()  # rows taken before each walk
    return set(map(str, ordered.index[before < cap]))



def walk_rows(obs: pd.DataFrame) -> list[NDArray[np.intp]]:
    """Row positions of each walk (``trace_id``) of an observation table: walks in order of
    first appearance, rows in table order."""
    if "trace_id" not in obs.columns:
        raise FingerprintError("observation table lacks columns ['trace_id']")
    code, _ = pd.factorize(obs["trace_id"], use_na_sentinel=False)
    order = np.argsort(code, kind="stable")
    return np.split(order, np.flatnonzero(np.diff(code[order])) + 1) if len(order) else []
