"""Results of localization: one estimate per step, and a walk's track."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

if TYPE_CHECKING:  # annotations: pyarrow and pandas are imported when a track is written
    import pandas as pd
    import pyarrow as pa

__all__ = ["Estimate", "Track"]


@dataclass(frozen=True)
class Estimate:
    """The position estimate after one step (or after the start).

    Attributes
    ----------
    t_ms : float
        Time of the step (Unix ms).
    x_m, y_m : float
        Estimated position (map frame, m).
    spread_m : float
        RMS distance of the particles from the estimate (m); for the alignment, the RMS
        spread of its shift; for Wi-Fi alone, the last fix's sigma; 0 for PDR.
    alive_fraction : float
        Share of particles whose last move stayed reachable (before resampling).
    recovered : bool
        True when all particles had died and were re-drawn around the last estimate.
    floor_id : str
    """

    t_ms: float
    x_m: float
    y_m: float
    spread_m: float = 0.0
    alive_fraction: float = 1.0
    recovered: bool = False
    floor_id: str = ""


@dataclass
class Track:
    """Per-step estimates of one walk (arrays of shape (m,)), plus the start estimate.

    Attributes
    ----------
    t_ms, x_m, y_m, spread_m, alive_fraction : ndarray
    recovered : ndarray of bool
    start : Estimate
        Where the filter started (before the first step).
    method : str
    trace_id, floor_id : str
    n_recoveries : int
    """

    t_ms: NDArray[np.float64]
    x_m: NDArray[np.float64]
    y_m: NDArray[np.float64]
    spread_m: NDArray[np.float64]
    alive_fraction: NDArray[np.float64]
    recovered: NDArray[np.bool_]
    start: Estimate
    method: str = ""
    trace_id: str = ""
    floor_id: str = ""
    info: dict = field(default_factory=dict)

    @classmethod
    def from_estimates(cls, start: Estimate, estimates: list[Estimate], **kw) -> Track:
        """The track of ``estimates`` (one per step) after ``start``; ``kw``: the other
        fields (``method``, ``trace_id``, ``floor_id``, ``info``)."""
        def col(name: str, dtype: DTypeLike = np.float64) -> NDArray:
            return np.array([getattr(e, name) for e in estimates], dtype=dtype)

        return cls(col("t_ms"), col("x_m"), col("y_m"), col("spread_m"), col("alive_fraction"),
                   col("recovered", bool), start, **kw)

    def __len__(self) -> int:
        return len(self.t_ms)

    def __repr__(self) -> str:  # what the track is, not its arrays
        span = f", {(self.t_ms[-1] - self.t_ms[0]) / 1000:.0f} s" if len(self) else ""
        smoothed = ", smoothed" if self.info.get("smoothed") else ""
        return (f"Track(method={self.method!r}, trace_id={self.trace_id!r}, "
                f"floor_id={self.floor_id!r}, {len(self)} steps{span}{smoothed}, "
                f"{self.n_recoveries} recoveries)")

    @property
    def n_recoveries(self) -> int:
        """How many steps re-drew the particles after all had died."""
        return int(np.count_nonzero(self.recovered))

    @property
    def xy_m(self) -> NDArray[np.float64]:
        """Step positions (m), shape (n_steps, 2): columns x, y."""
        return np.column_stack([self.x_m, self.y_m])

    def at(self, t_ms: ArrayLike) -> NDArray[np.float64]:
        """Positions (m) at times (Unix ms), linear between steps; before the first step the
        track moves from the start position (at the start time) to the first step; after
        the last step it stays. Shape (k, 2) for a time or k times (1-D), else the times'
        shape plus a last axis (x, y)."""
        t = np.asarray(t_ms, dtype=np.float64)
        tt = np.concatenate([[self.start.t_ms], self.t_ms]) if len(self) else np.array(
            [self.start.t_ms])
        xx = np.concatenate([[self.start.x_m], self.x_m])
        yy = np.concatenate([[self.start.y_m], self.y_m])
        if len(tt) > 1 and tt[0] >= tt[1]:
            tt = tt[1:]
            xx, yy = xx[1:], yy[1:]
        xy = np.stack([np.interp(t, tt, xx), np.interp(t, tt, yy)], axis=-1)
        return xy.reshape(-1, 2) if t.ndim <= 1 else xy

    def to_columns(self) -> dict[str, NDArray]:
        """Plain columns for a table: step, t_ms (whole ms, rounded to the nearest, halves to
        even: a streamed step's time may have a fraction), x_m, y_m, spread_m,
        alive_fraction, recovered."""
        return {"step": np.arange(len(self), dtype=np.int32),
                "t_ms": np.rint(self.t_ms).astype(np.int64), "x_m": self.x_m, "y_m": self.y_m,
                "spread_m": self.spread_m, "alive_fraction": self.alive_fraction,
                "recovered": self.recovered}

    def metadata(self) -> dict:
        """What a written track carries beside its columns: method, smoothed (True for an
        offline smoothed track), trace id, floor id, start position (m) and recoveries; and,
        for a track of a localizer's ``run``, what ran (``indoormap guided by align``), the
        bundle id and, for ``auto``, why it chose it
        (:meth:`localize.filter.BaseLocalizer.provenance`)."""
        return {"method": self.method, "smoothed": bool(self.info.get("smoothed")),
                "trace_id": self.trace_id, "floor_id": self.floor_id,
                "start_x_m": float(self.start.x_m), "start_y_m": float(self.start.y_m),
                "n_recoveries": int(self.n_recoveries),
                **{k: self.info[k] for k in ("ran", "bundle_id", "auto") if k in self.info}}

    def to_frame(self) -> pd.DataFrame:
        """The track as a pandas DataFrame, one row per step (the columns of
        :meth:`to_columns`; :meth:`metadata` in ``attrs``), for a notebook."""
        import pandas as pd

        frame = pd.DataFrame(self.to_columns())
        frame.attrs.update(self.metadata())
        return frame

    def to_arrow(self) -> pa.Table:
        """The track as a pyarrow Table (:meth:`metadata` as the schema's: text as it is,
        other values as JSON, e.g. smoothed ``true``/``false``)."""
        import pyarrow as pa

        text = {k: v if isinstance(v, str) else json.dumps(v)
                for k, v in self.metadata().items()}
        return pa.table(self.to_columns()).replace_schema_metadata(text)
