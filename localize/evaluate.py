"""Localization errors: at waypoints, at every step, and their summaries (numpy only)."""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.track import Track

__all__ = ["SeenWalkWarning", "step_errors", "summarize", "waypoint_errors"]


class SeenWalkWarning(UserWarning):
    """Errors measured on a walk the map was built from: better than an unseen walk's would
    be (the CLI says so in its own words and silences this one)."""


def _warn_if_seen(track: Track) -> None:
    if track.info.get("seen_by_map"):
        warnings.warn(f"{track.trace_id} was used to build the map of floor {track.floor_id}: "
                      "its errors are better than an unseen walk's would be (build without it: "
                      "exclude_walks)", SeenWalkWarning, stacklevel=3)


def waypoint_errors(track: Track, t_ms: ArrayLike, xy_m: ArrayLike) -> NDArray[np.float64]:
    """Distance (m) between the track (interpolated in time) and reference points.

    Parameters
    ----------
    track : Track
    t_ms : array_like (k,)
        Reference times (Unix ms), e.g. waypoint clicks.
    xy_m : array_like (k, 2)
        Reference positions (m); one point may be given as ``(x, y)``.

    Returns
    -------
    ndarray (k,)
        Before the track's first step the track is taken from its start to that step, after
        its last step at the last position (:meth:`Track.at`).

    Raises
    ------
    ValueError
        ``xy_m`` not of shape (k, 2); no reference time within
        :data:`REFERENCE_TIME_SLACK_MS` of the track's time span (times in seconds, or
        another walk's: each would be scored against the track's first or last position).

    Warns
    -----
    SeenWalkWarning
        The track's walk is one the map was built from (``track.info["seen_by_map"]``).
    """
    _warn_if_seen(track)
    t = np.asarray(t_ms, dtype=np.float64).reshape(-1)
    ref = xy_rows(xy_m, len(t), "waypoint_errors")
    _check_reference_times(track, t)
    est = track.at(t)
    return np.hypot(*(est - ref).T)


#: How far (ms) outside a track's time span (start to last step) reference times may all lie
#: before :func:`waypoint_errors` refuses them: a walker standing still before the first step
#: or after the last one is scored at the track's end, rightly; times in seconds are 1e12 ms off.
REFERENCE_TIME_SLACK_MS = 60_000.0


def _check_reference_times(track: Track, t: NDArray[np.float64]) -> None:
    if len(t) == 0:
        return
    if not np.isfinite(t).all():
        raise ValueError(f"waypoint_errors: {int((~np.isfinite(t)).sum())} of the {len(t)} "
                         "reference time(s) are not finite numbers (Unix ms)")
    t0 = track.start.t_ms
    t1 = float(track.t_ms[-1]) if len(track) else t0
    near = (t >= t0 - REFERENCE_TIME_SLACK_MS) & (t <= t1 + REFERENCE_TIME_SLACK_MS)
    if not near.any():
        raise ValueError(f"waypoint_errors: none of the {len(t)} reference time(s) "
                         f"({np.nanmin(t):.0f} to {np.nanmax(t):.0f}) lies within "
                         f"{REFERENCE_TIME_SLACK_MS / 1000:g} s of the track's "
                         f"{t0:.0f} to {t1:.0f} (Unix ms): times in seconds, or another "
                         "walk's?")


def xy_rows(xy_m: ArrayLike, n: int | None, where: str) -> NDArray[np.float64]:
    """``xy_m`` as an (n, 2) array (m), any number of rows when ``n`` is None (one point may
    be a flat ``(x, y)``); a ValueError naming ``where`` for any other shape (a (2, n) array
    was read row-major, its x and y mixed)."""
    ref = np.asarray(xy_m, dtype=np.float64)
    rows = "k" if n is None else str(n)
    transposed = ref.ndim == 2 and ref.shape[0] == 2 and ref.shape[1] != 2 and (
        n is None or ref.shape[1] == n)
    if n is None:
        n = 0 if ref.size == 0 else 1 if ref.shape == (2,) else \
            ref.shape[0] if ref.ndim == 2 else -1
    if (ref.size == 0 and n == 0) or (ref.shape == (2,) and n == 1):
        return ref.reshape(n, 2)
    if ref.shape != (n, 2):
        hint = " (transposed? one row per point)" if transposed else ""
        raise ValueError(f"{where}: positions of shape ({rows}, 2) expected, one row per "
                         f"point, got {ref.shape}{hint}")
    return ref


def step_errors(track: Track, true_xy_m: ArrayLike) -> NDArray[np.float64]:
    """Distance (m) between each step's estimate and the true position at that step
    (``true_xy_m`` shape (m, 2), one row per step of the track)."""
    _warn_if_seen(track)
    ref = xy_rows(true_xy_m, len(track), "step_errors")
    return np.hypot(track.x_m - ref[:, 0], track.y_m - ref[:, 1])


def summarize(errors_m: ArrayLike) -> dict[str, float]:
    """``n``, median, p80, mean and max of errors (NaN when empty).

    Examples
    --------
    >>> summarize([1.0, 2.0, 3.0, 4.0, 5.0])["p80"]
    4.2
    """
    e = np.asarray(errors_m, dtype=np.float64)
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {"n": 0, "median": float("nan"), "p80": float("nan"), "mean": float("nan"),
                "max": float("nan")}
    return {"n": int(e.size), "median": float(np.median(e)),
            "p80": float(np.percentile(e, 80)), "mean": float(e.mean()),
            "max": float(e.max())}
