"""Tests of survey.attitude (paper 001, Algorithm 2) on synthetic hand-held walks."""

from __future__ import annotations

import numpy as np
import pytest
from ilc_sample import ilc_walks, load_streams

from survey.attitude import (
    Attitude,
    AttitudeParams,
    classify_attitude,
    p_upward_forward,
)
from survey.errors import ProcessingError
from survey.steps import STANDARD_GRAVITY, detect_steps


def rx(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def ry(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def rz(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def walking_frame_signal(rng, n_steps=120, fs=50.0):
    """Specific force in the walking frame (x right, y forward, z up) and true step times.

    Vertical bounce ``A(-cos 2 pi phi + 0.2 cos(4 pi phi + 0.7))`` peaks at phi = k + 1/2 (the
    step events); forward ``0.5 A cos(2 pi (phi - 0.38))`` peaks a little before each vertical
    peak (paper 001 figure 6, event E1); lateral sway ``-L cos(pi phi)`` has the period of a
    stride and crosses zero at the vertical peaks, so its mean alternates in sign from one step
    cycle to the next (event E3). A in [1.5, 2.5] m/s^2 (10 % per-step jitter), L in
    [0.5, 0.9] m/s^2, step frequency 1.6-2.0 Hz with 3 % jitter.
    """
    f = rng.uniform(1.6, 2.0) * (1 + 0.03 * rng.standard_normal(n_steps))
    amp = rng.uniform(1.5, 2.5) * (1 + 0.1 * rng.standard_normal(n_steps))
    sway = rng.uniform(0.5, 0.9)
    dur = 1.0 / f
    edges = np.concatenate([[0.0], np.cumsum(dur)])
    n = int(edges[-1] * fs)
    t = np.arange(n) / fs
    k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, n_steps - 1)
    phi = k + (t - edges[k]) / dur[k]
    vert = amp[k] * (-np.cos(2 * np.pi * phi) + 0.2 * np.cos(4 * np.pi * phi + 0.7))
    fwd = 0.5 * amp[k] * np.cos(2 * np.pi * (phi - 0.38))
    lat = -sway * np.cos(np.pi * phi)
    force = np.column_stack([lat, fwd, STANDARD_GRAVITY + vert])
    return t * 1000.0, force, (edges[:-1] + 0.5 * dur) * 1000.0


def device_acc(rng, t_ms, force, attitude, noise=0.4, wobble_deg=2.0):
    """Device-frame readings for a phone with attitude ``attitude`` (device -> walking frame)
    plus a slow +-``wobble_deg`` hand wobble about the walking x and y axes and white noise."""
    t = t_ms / 1000.0
    w1 = np.radians(wobble_deg) * np.sin(2 * np.pi * 0.3 * t + rng.uniform(0, 2 * np.pi))
    w2 = np.radians(wobble_deg) * np.sin(2 * np.pi * 0.23 * t + rng.uniform(0, 2 * np.pi))
    x, y, z = force.T
    y1, z1 = np.cos(w1) * y + np.sin(w1) * z, -np.sin(w1) * y + np.cos(w1) * z   # Rx(w1)^T
    x2, z2 = np.cos(w2) * x - np.sin(w2) * z1, np.sin(w2) * x + np.cos(w2) * z1  # Ry(w2)^T
    v = np.column_stack([x2, y1, z2])
    return v @ attitude + noise * rng.standard_normal(v.shape)  # attitude^T v per row


# Attitudes (device -> walking frame). Tilting towards the eyes = rotation about the walking
# x axis, applied after turning the phone in the horizontal plane.
def ufh(rng):      # flat, top forward, tilted 5-10 deg towards the eyes
    return rx(rng.uniform(5, 10)) @ ry(rng.uniform(-2, 2))


def ufnh(rng):     # upright reading posture, ~60 deg
    return rx(rng.uniform(55, 62)) @ ry(rng.uniform(-3, 3))


def sideways_right(rng):  # top edge to the right (gaming / landscape)
    return rx(rng.uniform(5, 20)) @ rz(-90.0)


def sideways_left(rng):
    return rx(rng.uniform(5, 20)) @ rz(90.0)


def backwards(rng):
    return rx(rng.uniform(5, 20)) @ rz(180.0)


def upside_down(rng):
    return ry(180.0) @ rx(rng.uniform(-10, 10))


def pocket(rng):   # upright in a trouser pocket, screen facing the leg
    return rx(-90.0 + rng.uniform(-15, 15))


CASES = [(ufh, Attitude.UFH), (ufnh, Attitude.UFNH), (sideways_right, Attitude.UNF),
         (sideways_left, Attitude.UNF), (backwards, Attitude.UNF),
         (upside_down, Attitude.NOT_UPWARD), (pocket, Attitude.NOT_UPWARD)]


@pytest.mark.parametrize("make_attitude,expected", CASES,
                         ids=[c[0].__name__ for c in CASES])
def test_attitude_with_true_step_times(make_attitude, expected):
    fractions = []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        t, force, steps = walking_frame_signal(rng)
        acc = device_acc(rng, t, force, make_attitude(rng))
        res = classify_attitude(t, acc, steps)
        assert len(res) == len(steps)
        fractions.append(np.mean(res.attitude == expected))
    assert min(fractions) >= 0.95
    assert np.mean(fractions) >= 0.98


@pytest.mark.parametrize("make_attitude,expected", CASES,
                         ids=[c[0].__name__ for c in CASES])
def test_attitude_with_detected_steps(make_attitude, expected):
    correct = total = 0
    for seed in range(20, 26):
        rng = np.random.default_rng(seed)
        t, force, _ = walking_frame_signal(rng)
        acc = device_acc(rng, t, force, make_attitude(rng))
        st = detect_steps(t, acc)
        res = classify_attitude(t, acc, st.t_ms)
        correct += int(np.sum(res.attitude == expected))
        total += len(res)
    assert correct / total >= 0.95


def test_evidence_values():
    rng = np.random.default_rng(40)
    t, force, steps = walking_frame_signal(rng)
    acc = device_acc(rng, t, force, rx(60.0), wobble_deg=0.0)
    res = classify_attitude(t, acc, steps)
    inner = slice(2, -2)
    # eq. 2: incline of the stride-mean support force equals the phone pitch
    np.testing.assert_allclose(res.theta_deg[inner], 60.0, atol=3.0)
    np.testing.assert_allclose(res.mean_az_ms2[inner], STANDARD_GRAVITY * 0.5, atol=0.4)
    assert res.e2.all() and res.e3[inner].all()
    flat = classify_attitude(t, device_acc(rng, t, force, rx(8.0), wobble_deg=0.0), steps)
    # the forward push peaks in the latter half of the step cycle (E1) for most steps of a UF
    # phone (paper Table 2: 97 %; here noise and the vertical bounce leaking into a_y through
    # the 8 deg tilt move some maxima to the cycle start). E1 does not change the UF decision.
    assert flat.e1.mean() > 0.75
    np.testing.assert_allclose(flat.theta_deg[inner], 8.0, atol=2.0)


def test_flat_phone_needs_e2_margin():
    # Exactly flat: mean a_y ~ mean a_x ~ 0, E2 is decided by noise and wobble. The optional
    # margin restores UFH.
    fractions = []
    for seed in range(50, 54):
        rng = np.random.default_rng(seed)
        t, force, steps = walking_frame_signal(rng)
        acc = device_acc(rng, t, force, np.eye(3))
        res = classify_attitude(t, acc, steps, AttitudeParams(e2_margin_ms2=1.0))
        fractions.append(np.mean(res.attitude == Attitude.UFH))
    assert min(fractions) >= 0.95


def test_k1_k2_thresholds():
    rng = np.random.default_rng(60)
    t, force, steps = walking_frame_signal(rng)
    acc = device_acc(rng, t, force, rx(40.0), wobble_deg=0.0)
    assert np.mean(classify_attitude(t, acc, steps).attitude == "UFNH") > 0.95
    # k2 = 0.5 -> horizontal below 45 deg
    loose = classify_attitude(t, acc, steps, AttitudeParams(k2=0.5))
    assert np.mean(loose.attitude == "UFH") > 0.95
    # k1 = 0.8 -> upward only within ~37 deg of vertical: a 40 deg phone is not upward
    strict = classify_attitude(t, acc, steps, AttitudeParams(k1=0.8))
    assert np.mean(strict.attitude == "NU") > 0.95


def test_table4_lookup():
    e1 = [1, 0, 1, 1, 0, 0, 1, 0]
    e2 = [1, 1, 0, 1, 1, 0, 0, 0]
    e3 = [1, 1, 1, 0, 0, 1, 0, 0]
    np.testing.assert_allclose(p_upward_forward(e1, e2, e3),
                               [1.0, 1.0, 0.0, 0.0633, 0.0, 0.0, 0.0, 0.0])


def test_enum_values_compare_with_codes():
    assert Attitude.UFH == "UFH" and Attitude.NOT_UPWARD == "NU"
    rng = np.random.default_rng(70)
    t, force, steps = walking_frame_signal(rng, n_steps=20)
    res = classify_attitude(t, device_acc(rng, t, force, ufh(rng)), steps)
    assert {Attitude(a) for a in res.attitude} <= set(Attitude)


def test_edge_cases():
    rng = np.random.default_rng(80)
    t, force, steps = walking_frame_signal(rng, n_steps=30)
    acc = device_acc(rng, t, force, ufh(rng))
    empty = classify_attitude(t, acc, [])
    assert len(empty) == 0 and empty.attitude.shape == (0,)
    # steps beyond the recording have no samples -> UNKNOWN
    res = classify_attitude(t, acc, np.concatenate([steps, [t[-1] + 5000.0]]))
    assert res.attitude[-1] == Attitude.UNKNOWN
    one = classify_attitude(t, acc, steps[5:6])
    assert len(one) == 1
    with pytest.raises(ProcessingError):
        classify_attitude(t, acc[:, :2], steps)
    with pytest.raises(ProcessingError):
        classify_attitude(t, acc, steps[::-1])
    with pytest.raises(ProcessingError):
        classify_attitude(t[::-1], acc, steps)


@pytest.mark.shared
def test_real_traces_are_upward_and_horizontal():
    # ILC surveyors hold the phone flat in front of the body: never NOT_UPWARD, incline small.
    # (With the paper's E2/E3 rules only 35-65 % of these steps come out UFH, the rest UNF: the
    # phone is so flat that E2 is a coin toss, and E3 misses 10-40 % of the steps.)
    for path in ilc_walks("F1", 5):
        acc = load_streams(path, ("TYPE_ACCELEROMETER",))["TYPE_ACCELEROMETER"]
        st = detect_steps(acc[:, 0], acc[:, 1:4])
        res = classify_attitude(acc[:, 0], acc[:, 1:4], st.t_ms)
        assert np.mean(res.attitude == Attitude.NOT_UPWARD) < 0.01
        assert np.median(np.abs(res.theta_deg)) < 10.0
        assert np.mean(np.isin(res.attitude, ["UFH", "UNF"])) > 0.95
