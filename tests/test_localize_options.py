"""Options of the filter: mode estimate, injection, particle shrinking, step models, radio."""

from __future__ import annotations

import numpy as np
import pytest
from localize_fixtures import f1_bundle, sim_walks, truth_bundles  # noqa: F401  (fixtures)

from localize.errors import LocalizationError
from localize.evaluate import step_errors
from localize.filter import Localizer
from localize.maps import FilterMap
from localize.params import FilterParams
from localize.particles import (
    ParticleState,
    estimate,
    estimate_mode,
    init_state,
    inject,
)
from localize.radio import KnnRadioPositioner, RadioModel
from localize.steps import RadioScan


def _state(x, y, w=None):
    st = ParticleState(1, len(x), {})
    st.x, st.y = np.asarray(x, float), np.asarray(y, float)
    st.w = np.ones(len(x)) if w is None else np.asarray(w, float)
    return st


def test_mode_estimate_stays_on_the_heavier_hypothesis():
    rng = np.random.default_rng(0)
    x = np.r_[rng.normal(10, 0.3, 700), rng.normal(20, 0.3, 300)]
    y = np.r_[rng.normal(5, 0.3, 700), rng.normal(5, 0.3, 300)]
    st = _state(x, y)
    mx, _, spread = estimate(st, uniform=True)
    ox, oy = estimate_mode(st)
    assert 12 < mx[0] < 14 and spread[0] > 4  # the mean falls between the two corridors
    assert abs(ox[0] - 10) < 0.2 and abs(oy[0] - 5) < 0.2
    st.w = np.r_[np.full(700, 0.1), np.full(300, 1.0)]  # weights decide, not counts
    assert abs(estimate_mode(st)[0][0] - 20) < 0.2


def test_injection_puts_a_share_of_particles_around_the_fix(f1_bundle):  # noqa: F811
    p = FilterParams()
    fm = FilterMap(f1_bundle)
    rng = np.random.default_rng(1)
    cell = fm.reachable_cells_xy[len(fm.reachable_cells_xy) // 2]
    st = init_state(fm, p, rng, np.array([cell]), np.array([1.0]))
    far = fm.reachable_cells_xy[0]
    k = inject(st, fm, p, rng, 0, 0.2, far, 2.0)
    assert k == 60
    d = np.hypot(st.x[0] - far[0], st.y[0] - far[1])
    assert np.count_nonzero(d < 3.0) >= 60
    assert fm.reachable(st.x, st.y).all()


def test_start_with_many_particles_then_shrink(f1_bundle, sim_walks):  # noqa: F811
    w = next(v for v in sim_walks if v.floor == "F1")
    p = FilterParams(n_particles=200, n_particles_start=1500, shrink_after_steps=10)
    loc = Localizer(f1_bundle, p, rng=0)
    loc.start(*w.start_xy)
    assert loc.state.shape == (1, 1500)
    for s in list(w.steps)[:12]:
        loc.step(s)
    assert loc.state.shape == (1, 200)


def test_weinberg_step_model(f1_bundle, sim_walks):  # noqa: F811
    w = next(v for v in sim_walks if v.floor == "F1")
    p = FilterParams(step_model="weinberg", genome_a_mean=0.38)
    t = Localizer(f1_bundle, p, rng=0).run(w.steps, start_xy=w.start_xy)
    # the simulated walker ties step length to frequency, not to the acceleration swing, so
    # this model fits the simulation worse than the default: a loose bound
    assert np.median(step_errors(t, w.true_xy)) < 3.0
    # the swing drives the length: a 16 times larger swing doubles F = swing^(1/4)
    big = w.steps.with_columns(delta_acc_ms2=w.steps.delta_acc_ms2 * 16.0)
    p0 = FilterParams(step_model="weinberg", genome_a_mean=0.38, weight_mode="none",
                      genome_drift_a=0.0, genome_drift_b=0.0, step_length_range_m=(0.1, 5.0))
    a = Localizer(f1_bundle, p0, rng=0)
    b = Localizer(f1_bundle, p0, rng=0)
    a.start(*w.start_xy)
    b.start(*w.start_xy)
    ea, eb = a.step(w.steps[5]), b.step(big[5])
    assert np.hypot(eb.x_m - w.start_xy[0], eb.y_m - w.start_xy[1]) > \
        np.hypot(ea.x_m - w.start_xy[0], ea.y_m - w.start_xy[1])
    with pytest.raises(LocalizationError):
        FilterParams(step_model="stride")


def test_radio_fix_and_likelihood():
    keys = np.array(["a", "b", "c"])
    xy = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    rssi = np.array([[-40, -70, -90], [-70, -40, -70], [-90, -70, -40]], dtype=float)
    r = KnnRadioPositioner(keys, xy, rssi, k=1, min_common=2, likelihood_k=2,
                           likelihood_sigma_m=2.0)
    scan = RadioScan(0, np.array(["a", "b", "zz"]), np.array([-70.0, -41.0, -50.0]))
    x, y, sigma = r.locate(scan)
    assert (x, y) == (10.0, 0.0) and sigma >= 1.0
    lk = r.likelihood(scan, np.array([0.0, 10.0, 20.0, 40.0]), np.zeros(4))
    assert np.argmax(lk) == 1 and lk[3] < 1e-6
    assert r.locate(RadioScan(0, np.array(["zz"]), np.array([-50.0]))) is None
    with pytest.raises(LocalizationError):
        KnnRadioPositioner(keys, xy, rssi[:2])


class _TruthRadio:
    """A radio model that knows where each scan was taken (plus 1.5 m of noise)."""

    def __init__(self, steps, true_xy, seed=0):
        self.t = steps.t_ms
        self.xy = true_xy
        self.rng = np.random.default_rng(seed)

    def locate(self, scan):
        i = int(np.clip(np.searchsorted(self.t, scan.t_ms), 0, len(self.t) - 1))
        x, y = self.xy[i] + self.rng.normal(0, 1.5, 2)
        return float(x), float(y), 2.0


def test_radio_updates_and_injection_run(f1_bundle, sim_walks):  # noqa: F811
    walks = [v for v in sim_walks if v.floor == "F1"]
    w = max(walks, key=lambda v: sum(s is not None for s in v.steps.scans))
    radio = _TruthRadio(w.steps, w.true_xy)
    # a wrong start 8 m away: radio updates and re-injection around the fixes bring it back
    wrong = (w.true_xy[0, 0] + 8.0, w.true_xy[0, 1])
    p = FilterParams(radio_update=True, radio_inject_fraction=0.1, radio_inject_distance_m=4.0,
                     mode_spread_m=2.0, n_particles_start=1000, init_half_width_m=1.0)
    t = Localizer(f1_bundle, p, radio=radio, rng=0).run(w.steps, start_xy=wrong)
    e = step_errors(t, w.true_xy)
    assert np.median(e[len(e) // 2:]) < 2.0
    assert isinstance(radio, RadioModel)  # the protocol is structural: locate() suffices


class _FarRadio:
    """Every scan's fix is 20 m east of the true position; the likelihood is a Gaussian there."""

    def __init__(self, steps, true_xy):
        self.t, self.xy = steps.t_ms, true_xy

    def _at(self, scan):
        i = int(np.clip(np.searchsorted(self.t, scan.t_ms), 0, len(self.t) - 1))
        return self.xy[i] + np.array([20.0, 0.0])

    def locate(self, scan):
        x, y = self._at(scan)
        return float(x), float(y), 2.0

    def likelihood(self, scan, x, y):
        fx, fy = self._at(scan)
        return np.exp(-((np.asarray(x) - fx) ** 2 + (np.asarray(y) - fy) ** 2) / 18.0)


def test_fit_rule_injects_when_the_radio_stops_agreeing(f1_bundle, sim_walks,  # noqa: F811
                                                        monkeypatch):
    """Augmented MCL: while the cloud fits the radio as well as it did, nothing is injected;
    when the fits drop, a share up to ``radio_inject_fraction`` is."""
    w = next(v for v in sim_walks if v.floor == "F1")
    p = FilterParams(radio_inject_rule="fit", radio_inject_fraction=0.3)
    loc = Localizer(f1_bundle, p, rng=0)
    loc.start(*w.start_xy)
    st = loc.state
    ones = np.ones(st.shape[1])
    assert [loc._fit_share(st, ones) for _ in range(5)] == [0.0] * 5
    shares = [loc._fit_share(st, 0.01 * ones) for _ in range(3)]
    assert 0 < shares[0] <= shares[1] <= shares[2] <= 0.3
    assert shares[2] == pytest.approx(0.3)
    # end to end: a radio right for the first half of the walk, then 20 m off
    w = max((v for v in sim_walks if v.floor == "F1"),
            key=lambda v: sum(s is not None for s in v.steps.scans))
    radio = _FarRadio(w.steps, w.true_xy)
    half = w.steps.t_ms[len(w.steps) // 2]
    radio._at = lambda scan, at=radio._at: at(scan) - (
        np.array([20.0, 0.0]) if scan.t_ms < half else 0.0)
    seen = []
    real_fit = Localizer._fit_share
    monkeypatch.setattr(Localizer, "_fit_share",
                        lambda self, st, lk: seen.append(real_fit(self, st, lk)) or seen[-1])
    Localizer(f1_bundle, p, radio=radio, rng=0).run(w.steps, start_xy=tuple(w.true_xy[0]))
    t_scans = np.array([sc.t_ms for sc in w.steps.scans if sc is not None])
    before, after = np.array(seen)[t_scans < half], np.array(seen)[t_scans >= half]
    assert after.max() == pytest.approx(0.3) and after[:3].sum() > 0.5
    assert before.mean() < 0.1
    with pytest.raises(LocalizationError, match="radio_inject_rule"):
        FilterParams(radio_inject_rule="sometimes")


def test_gaussian_update_never_makes_nan_from_dead_particles():
    """A dead particle (w = 0) fitting better than every living one gave 0 * exp(+big) = NaN."""
    from localize.update import gaussian_update

    st = ParticleState(1, 4, {"strength": (1, 1)})
    st.w = np.array([[0.0, 1.0, 1.0, 0.0]])
    st.terms["strength"][0] = np.array([[0.0, 5000.0, 6000.0, 1e-9]])
    gaussian_update(st, FilterParams(weight_mode="gaussian", gaussian_window=1))
    assert np.isfinite(st.w).all() and st.w[0, 0] == 0.0 and st.w[0, 1] == 1.0
