"""Magnetic field model of the simulator: realistic strength, inclination and spectrum."""

from __future__ import annotations

import json

import numpy as np
import pytest

from survey.sim.field import EarthField, FieldParams, MagneticField, make_field
from survey.sim.floorplan import make_floorplan
from survey.sim.rng import child_rng


@pytest.fixture(scope="module")
def floor_and_field():
    plan = make_floorplan("F1", 0, 40.0, 25.0, (5.0, 3.0, 1.2), (2.5, 4.0, 1.2),
                          child_rng(3, "plan"))
    return plan, make_field(plan, FieldParams(), child_rng(3, "field"))


def _walkable_grid(plan, step=0.25):
    xs = np.arange(step / 2, plan.width_m, step)
    ys = np.arange(step / 2, plan.height_m, step)
    gx, gy = (a.ravel() for a in np.meshgrid(xs, ys))
    keep = plan.is_walkable(gx, gy)
    return gx[keep], gy[keep]


def test_earth_field_vector():
    b = EarthField(42.0, 133.0, 0.0).vector_ut()
    assert np.linalg.norm(b) == pytest.approx(42.0)
    assert b[0] == pytest.approx(0.0, abs=1e-12)           # horizontal part points to map north
    assert b[1] == pytest.approx(42.0 * np.sin(np.radians(133.0)))
    assert b[2] == pytest.approx(-28.64, abs=0.01)          # vertical ~ -29 uT, as measured


def test_strength_and_inclination_realistic(floor_and_field):
    plan, field = floor_and_field
    x, y = _walkable_grid(plan)
    b = field.field_earth_ut(x, y)
    s = np.linalg.norm(b, axis=1)
    assert s.min() >= 25.0 and s.max() <= 65.0
    assert 3.0 <= s.std() <= 9.0                            # real floors: SD ~5-7 uT
    incl = np.degrees(np.arccos(b[:, 2] / s))                # angle from up
    assert np.median(incl) == pytest.approx(133.0, abs=4.0)
    dev = field.compass_deviation_deg(x, y)
    assert np.all((dev >= -180.0) & (dev < 180.0))
    assert 1.0 < np.std(dev) < 20.0


def test_spectrum_mostly_below_half_cycle_per_metre(floor_and_field):
    plan, field = floor_and_field
    fractions = []
    for wl in plan.walk_lines:
        length = wl.line.length
        d = np.arange(0.0, length, 0.1)
        pts = np.array([wl.line.interpolate(v).coords[0] for v in d])
        b = field.field_earth_ut(pts[:, 0], pts[:, 1])
        a = b - b.mean(axis=0)
        power = np.abs(np.fft.rfft(a * np.hanning(len(a))[:, None], axis=0)) ** 2
        freq = np.fft.rfftfreq(len(a), d=0.1)
        fractions.append(power[freq < 0.5].sum() / power.sum())
    assert min(fractions) > 0.9
    assert np.median(fractions) > 0.97


def test_field_is_varied_on_the_metre_scale(floor_and_field):
    plan, field = floor_and_field
    wl = max(plan.walk_lines, key=lambda w: w.line.length)
    d = np.arange(0.0, wl.line.length, 0.5)
    pts = np.array([wl.line.interpolate(v).coords[0] for v in d])
    s = field.strength_ut(pts[:, 0], pts[:, 1])
    assert np.abs(np.diff(s)).mean() > 0.1                   # not flat
    assert np.abs(np.diff(s)).max() < 15.0                   # no jumps between 0.5 m samples


def test_dict_round_trip_is_exact(floor_and_field):
    plan, field = floor_and_field
    again = MagneticField.from_dict(json.loads(json.dumps(field.to_dict())))
    x, y = _walkable_grid(plan, 1.0)
    np.testing.assert_array_equal(again.field_earth_ut(x, y), field.field_earth_ut(x, y))


def test_compass_deviation_sign():
    earth = EarthField()
    undisturbed = MagneticField(earth, np.zeros((0, 3)), np.zeros((0, 3)))
    assert undisturbed.compass_deviation_deg(np.array([1.0]), np.array([2.0]))[0] == 0.0
    # a dipole west of the point, moment pointing east, adds an eastward field -> positive
    dip = MagneticField(earth, np.array([[-2.0, 0.0, 1.1]]), np.array([[200.0, 0.0, 0.0]]))
    assert dip.compass_deviation_deg(np.array([0.0]), np.array([0.0]))[0] > 5.0
