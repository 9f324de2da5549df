"""Smoothing by genealogy (localize.smoothing) and the filter's offline mode."""

from __future__ import annotations

import numpy as np
import pytest
from localize_fixtures import f1_bundle, sim_walks, truth_bundles  # noqa: F401  (fixtures)

from localize.baselines import make_localizer
from localize.errors import LocalizationError
from localize.evaluate import step_errors
from localize.filter import Localizer
from localize.params import FilterParams
from localize.particles import ParticleState, resample
from localize.smoothing import Genealogy


def test_paths_are_traced_back_through_ancestors() -> None:
    g = Genealogy()
    g.record([0.0, 10.0, 20.0], [0.0, 0.0, 0.0], None)
    g.record([1.0, 11.0, 21.0], [0.0, 0.0, 0.0], [0, 1, 2])
    # only particle 2's descendants survive, then particle 0 of record 2 carries on twice
    g.record([22.0, 22.5], [1.0, 1.0], [2, 2])
    g.record([23.0, 30.0, 23.5], [2.0, 2.0, 2.0], [0, 0, 1])
    sx, sy, traced = g.smoothed()
    np.testing.assert_allclose(sx, [20.0, 21.0, (22.0 * 2 + 22.5) / 3, (23.0 + 30.0 + 23.5) / 3])
    np.testing.assert_allclose(sy, [0.0, 0.0, 1.0, 2.0])
    assert traced.all()
    # the filter alone would have said 10 and 11 for the first two records
    sx_w, _, _ = g.smoothed(final_weights=[0.0, 0.0, 1.0])  # only the path via record-2 slot 1
    np.testing.assert_allclose(sx_w, [20.0, 21.0, 22.5, 23.5])


def test_broken_lineages_restart_from_that_step() -> None:
    g = Genealogy()
    g.record([0.0, 2.0], [0.0, 0.0], None)
    g.record([5.0, 7.0], [0.0, 0.0], [0, 1])
    g.record([50.0, 52.0], [0.0, 0.0], [-1, -1])  # all re-drawn (a recovery)
    g.record([53.0, 60.0], [0.0, 0.0], [1, -1])   # one injected particle
    sx, _, traced = g.smoothed()
    # record 3: both; record 2: only the lineage of slot 0 (-> slot 1 of record 2)
    np.testing.assert_allclose(sx, [1.0, 6.0, 52.0, 56.5])
    assert traced.tolist() == [False, False, True, True]


def test_bad_records_are_refused() -> None:
    g = Genealogy()
    with pytest.raises(ValueError, match="first record"):
        g.record([0.0], [0.0], [0])
    g.record([0.0, 1.0], [0.0, 1.0], None)
    with pytest.raises(ValueError, match="slots of the previous record"):
        g.record([0.0], [0.0], [2])
    with pytest.raises(ValueError, match="parents"):
        g.record([0.0, 1.0], [0.0, 1.0], [0])
    with pytest.raises(ValueError, match="final_weights"):
        g.smoothed(final_weights=[1.0, -1.0])
    assert Genealogy().smoothed()[0].shape == (0,)


def test_lineage_follows_resampling() -> None:
    rng = np.random.default_rng(2)
    st = ParticleState(2, 50, {}, with_lineage=True)
    st.reset_lineage()
    st.x = np.arange(100, dtype=float).reshape(2, 50)
    st.w = rng.random((2, 50)) ** 4
    before = st.x.copy()
    resample(st, rng, n_out=20)
    lin = st.lineage.astype(int)
    assert lin.shape == (2, 20)
    np.testing.assert_array_equal(st.x, np.take_along_axis(before, lin, axis=1))
    st.cut_lineage(1, [0, 3])
    assert (st.lineage[1, [0, 3]] == -1).all() and (st.lineage[0] >= 0).all()
    with pytest.raises(AttributeError):
        ParticleState(1, 5, {}).lineage  # noqa: B018


def _f1(walks):
    return [w for w in walks if w.floor == "F1"]


def test_smoothing_keeps_the_filter_and_fixes_a_wrong_start(f1_bundle, sim_walks):  # noqa: F811
    """Start 5 m off the truth (as a Wi-Fi fix would be), particles spread 6 m either way. The
    last smoothed position is the filter's, and over the first 20 steps (before the filter has
    converged) the smoothed positions are far nearer the truth (measured: mean error 0.33 m
    against the filter's 2.71 m)."""
    first_f, first_s = [], []
    for w in _f1(sim_walks)[:6]:
        start = (w.start_xy[0] + 3.0, w.start_xy[1] + 4.0)
        plain, smooth = (Localizer(f1_bundle, FilterParams(), rng=4).run(
            w.steps, start_xy=start, half_width_m=6.0, smooth=s) for s in (False, True))
        assert smooth.info["smoothed"] and not plain.info["smoothed"]
        np.testing.assert_allclose(smooth.x_m[-1], plain.x_m[-1], atol=1e-9)
        first_f.append(step_errors(plain, w.true_xy)[:20])
        first_s.append(step_errors(smooth, w.true_xy)[:20])
    f, s = np.concatenate(first_f).mean(), np.concatenate(first_s).mean()
    assert s < 0.3 * f, (s, f)


def test_only_particle_filters_smooth(f1_bundle, sim_walks):  # noqa: F811
    w = _f1(sim_walks)[0]
    with pytest.raises(LocalizationError, match="cannot smooth"):
        make_localizer("pdr", f1_bundle).run(w.steps, start_xy=w.start_xy, smooth=True)
