"""Simulated walkers: true path inside the walkable area, realistic stray, steps and clicks."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString

from survey.sim.floorplan import make_floorplan
from survey.sim.rng import child_rng
from survey.sim.routes import build_graph, click_points, random_route
from survey.sim.walker import WalkerParams, simulate_walk

START_MS = 1_700_000_000_000


@pytest.fixture(scope="module")
def walks():
    plan = make_floorplan("F1", 0, 40.0, 25.0, (5.0, 3.0, 1.2), (2.5, 4.0, 1.2),
                          child_rng(11, "plan"))
    graph = build_graph(plan)
    out = []
    for i in range(16):
        route = click_points(random_route(graph, 45.0, child_rng(11, "route", i)))
        out.append(simulate_walk(route, plan, START_MS + i * 100_000, WalkerParams(),
                                 child_rng(11, "walk", i)))
    return plan, out


def test_true_path_stays_in_walkable_area(walks):
    plan, ws = walks
    for k in ws:
        assert plan.is_walkable(k.xy_m[:, 0], k.xy_m[:, 1]).all()
        assert plan.is_walkable(k.path.xy_m[:, 0], k.path.xy_m[:, 1],
                                margin_m=0.2).all()


def test_path_strays_one_to_two_metres_from_waypoint_lines(walks):
    _, ws = walks
    leg_max = []
    for k in ws:
        for a, b, ta, tb in zip(k.clicks_m[:-1], k.clicks_m[1:], k.click_true_t_ms[:-1],
                                k.click_true_t_ms[1:]):
            if np.linalg.norm(b - a) < 3.0:
                continue                                   # lane changes at crossings
            sel = (k.t_ms >= ta) & (k.t_ms <= tb)
            d = shapely.distance(LineString([a, b]), shapely.points(k.xy_m[sel]))
            leg_max.append(d.max())
    leg_max = np.asarray(leg_max)
    assert len(leg_max) > 50
    assert 0.5 <= np.median(leg_max) <= 2.0
    assert 0.9 <= np.percentile(leg_max, 80) <= 2.5
    assert leg_max.max() <= 3.5


def test_clicks_position_and_timing_errors(walks):
    _, ws = walks
    pos_err = np.concatenate([np.linalg.norm(k.click_true_xy_m - k.clicks_m, axis=1)
                              for k in ws])
    t_err = np.concatenate([(k.click_t_ms - k.click_true_t_ms) / 1000.0 for k in ws])
    assert 0.15 <= np.sqrt(np.mean(pos_err ** 2)) <= 0.6
    assert 0.15 <= np.std(t_err) <= 0.5
    for k in ws:
        assert np.all(np.diff(k.click_t_ms) > 0)
        assert k.start_ms <= k.click_t_ms[0] and k.click_t_ms[-1] <= k.end_ms


def test_timeline_steps_and_pace(walks):
    _, ws = walks
    n_pauses = 0
    for k in ws:
        dt = np.diff(k.t_ms)
        assert np.all(dt > 0) and np.median(dt) == 20
        assert k.start_ms < k.t_ms[0] and k.t_ms[-1] <= k.end_ms
        walking = k.moving > 0.99
        assert 0.7 <= np.mean(k.speed_mps[walking]) <= 1.4
        period = np.diff(k.step_t_ms) / 1000.0
        freq = 1.0 / np.median(period)
        assert 1.5 <= freq <= 2.1
        assert np.sum(k.step_length_m) == pytest.approx(k.length_m, abs=1.0)
        assert np.all(k.step_length_m[1:] < 1.0)
        # standing at both ends
        assert k.moving[0] == 0.0 and k.moving[-1] == 0.0
        stops = np.flatnonzero(np.diff((k.moving == 0).astype(int)) == 1)
        n_pauses += max(0, len(stops) - 1)
    assert n_pauses >= 3                                   # some walks pause on the way


def test_same_rng_same_walk(walks):
    plan, _ = walks
    graph = build_graph(plan)
    route = click_points(random_route(graph, 30.0, child_rng(5, "r")))
    a = simulate_walk(route, plan, START_MS, WalkerParams(), child_rng(5, "w"))
    b = simulate_walk(route, plan, START_MS, WalkerParams(), child_rng(5, "w"))
    np.testing.assert_array_equal(a.t_ms, b.t_ms)
    np.testing.assert_array_equal(a.xy_m, b.xy_m)
