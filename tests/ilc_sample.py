"""Minimal loader of ILC sample traces for the ``shared`` real-data checks of the survey-math
tests (sensor streams and waypoints only; the full reader is ``survey.trace_reader``)."""

from __future__ import annotations

import gzip
import os
from pathlib import Path

import numpy as np
import pytest

#: The real ILC traces: ``$INDOORMAP_ILC`` when set (the folder holding ``site1/``, e.g. for a
#: checkout elsewhere than beside ``shared``), else ``../shared/ilc``.
SHARED_ILC = Path(os.environ.get("INDOORMAP_ILC")
                  or Path(__file__).resolve().parents[1].parent / "shared" / "ilc")
SKIP_REASON = f"{SHARED_ILC} is not available (set INDOORMAP_ILC to the ILC traces' folder)"


def ilc_walks(floor: str = "F1", count: int = 5) -> list[Path]:
    """The first ``count`` trace files of ``site1/<floor>``, or skip the test."""
    folder = SHARED_ILC / "site1" / floor / "path_data_files"
    if not folder.is_dir():
        pytest.skip(SKIP_REASON)
    return sorted(folder.glob("*.txt.gz"))[:count]


def load_streams(path: Path, types: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Per record type, a time-sorted float array: column 0 the time (ms), then the values."""
    rows: dict[str, list[list[str]]] = {t: [] for t in types}
    with gzip.open(path, "rt", encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if line.startswith("#"):
                continue
            parts = line.rstrip("\n").split("\t")
            if len(parts) > 2 and parts[1] in rows:
                rows[parts[1]].append([parts[0], *parts[2:]])
    out = {}
    for t, r in rows.items():
        width = min(len(x) for x in r) if r else 1
        a = np.array([x[:width] for x in r], dtype=np.float64).reshape(len(r), width)
        out[t] = a[np.argsort(a[:, 0], kind="stable")]
    return out
