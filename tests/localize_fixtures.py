"""Shared fixtures of the localizer tests: truth bundles and walks of ``data/sample_site``."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from localize.bundle import load_bundle
from localize.steps import StepSummaries

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "data" / "sample_site"


@dataclass
class SimWalk:
    trace_id: str
    floor: str
    steps: StepSummaries
    true_xy: np.ndarray        # (m, 2) true position at every step
    start_xy: np.ndarray       # true position half a second before the first step
    wp_t: np.ndarray           # recorded waypoints
    wp_xy: np.ndarray
    trace_path: Path


def site_json() -> dict:
    return json.loads((SAMPLE / "truth" / "site.json").read_text())


@pytest.fixture(scope="session")
def truth_bundles(tmp_path_factory) -> dict[str, Path]:
    """Truth bundles (0.25 m) of both sample floors: floor name -> bundle folder."""
    from survey.sim.truth_bundle import truth_bundle

    root = tmp_path_factory.mktemp("bundles")
    out = {}
    for floor in ("F1", "F2"):
        truth_bundle(SAMPLE, floor, root / floor)
        out[floor] = root / floor
    return out


@pytest.fixture(scope="session")
def f1_bundle(truth_bundles):
    return load_bundle(truth_bundles["F1"])


@pytest.fixture(scope="session")
def sim_walks() -> list[SimWalk]:
    """Every sample walk with its step summaries and truth."""
    from survey.step_summaries import step_summaries, waypoints_of
    from survey.trace_reader import read_trace

    out = []
    for w in site_json()["walks"]:
        path = SAMPLE / w["trace_path"]
        trace = read_trace(path)
        steps = step_summaries(trace)
        truth = pd.read_parquet(SAMPLE / w["truth_path"])
        tt = truth["t_ms"].to_numpy(np.float64)

        def at(t, tt=tt, truth=truth):
            return np.column_stack([np.interp(t, tt, truth["x_m"]), np.interp(t, tt,
                                                                             truth["y_m"])])

        wp_t, wp_xy = waypoints_of(trace)
        out.append(SimWalk(w["trace_id"], w["floor"], steps, at(steps.t_ms),
                           at([steps.t_ms[0] - 500.0])[0], wp_t, wp_xy, path))
    return out
