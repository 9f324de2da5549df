"""Matchers: accuracy on the simulated site, the stated missing-AP policy, kernels."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from radio_fixtures import sample_store, split_walks, walk_ids, wifi_obs  # noqa: F401

from localize.radio_match import (
    gaussian_loglik,
    knn_positions,
    powed,
    reference_neighbours,
    smoothed_distances,
    sorensen_distances,
)
from mapping.errors import FingerprintError
from mapping.fingerprints import build_fingerprints
from mapping.matching import GaussianMatch, WeightedKNN, default_matcher
from mapping.radio_scans import ScanSet, scan_set


def _lowo(obs, matcher, **build) -> np.ndarray:
    errs = []
    for held in walk_ids(obs):
        train, test = split_walks(obs, held)
        scans = scan_set(test)
        res = matcher.fit(build_fingerprints(train, **build)).predict(scans)
        errs.append(np.linalg.norm(res.xy_m - scans.xy_m, axis=1))
    return np.concatenate(errs)


def test_default_beats_plain_knn_on_the_simulated_site(wifi_obs):
    obs = wifi_obs["F2"]
    default = _lowo(obs, default_matcher())
    plain = _lowo(obs, WeightedKNN(5, weight_power=0, metric="euclidean",
                                   representation="dbm"), cell_m=0, max_age_ms=None)
    gauss = _lowo(obs, GaussianMatch(), cell_m=2.0)
    assert np.isfinite(default).all()
    assert np.median(default) < 3.0                      # 2.1 m when written
    assert np.median(default) < np.median(plain)
    assert np.median(gauss) < 2 * np.median(plain)


def _tiny_db():
    obs = pd.DataFrame({
        "trace_id": "w", "scan_id": [0, 0, 1, 1, 2], "t_ms": [0, 0, 2000, 2000, 4000],
        "x_m": [0.5, 0.5, 10.5, 10.5, 20.5], "y_m": 0.5,
        "ap": ["a", "b", "b", "c", "c"], "rssi_dbm": [-50.0, -80, -50, -80, -50],
        "age_ms": 0.0})
    return build_fingerprints(obs, cell_m=1.0)


def _scans(rows: dict[str, float]) -> ScanSet:
    aps = np.array(sorted(rows), dtype=str)
    rssi = np.array([[rows[a] for a in aps]], dtype=float)
    scans = pd.DataFrame({"scan_id": [0], "trace_id": ["q"], "t_ms": [0], "x_m": [np.nan],
                          "y_m": [np.nan], "n_aps": [len(aps)]})
    return ScanSet(scans, aps, rssi, np.zeros_like(rssi))


@pytest.mark.parametrize("matcher", [WeightedKNN(1), GaussianMatch(1),
                                     WeightedKNN(1, metric="euclidean", representation="dbm")])
def test_scan_with_no_known_ap_gets_nan(matcher):
    matcher.fit(_tiny_db())
    res = matcher.predict(_scans({"zz": -40.0}))
    assert np.isnan(res.xy_m).all() and np.isnan(res.score).all()
    assert res.n_aps.tolist() == [0] and res.neighbours.tolist() == [[-1]]


@pytest.mark.parametrize("matcher", [WeightedKNN(1), GaussianMatch(1)])
def test_unknown_aps_are_ignored(matcher):
    matcher.fit(_tiny_db())
    plain = matcher.predict(_scans({"a": -52.0, "b": -79.0}))
    extra = matcher.predict(_scans({"a": -52.0, "b": -79.0, "zz": -30.0, "yy": -45.0}))
    assert np.allclose(plain.xy_m, extra.xy_m) and np.allclose(plain.score, extra.score)
    assert plain.xy_m[0, 0] == pytest.approx(0.5) and plain.n_aps[0] == extra.n_aps[0] == 2


def test_gaussian_policy_heard_but_absent_costs_unheard_is_free():
    db = _tiny_db()
    g = GaussianMatch(1).fit(db)
    both = g.loglik(_scans({"a": -50.0, "b": -80.0}))[0]
    # RP 0 heard a and b as the scan did; RPs 1 and 2 lack a (and b): the wide guess costs
    assert both[0] > both[1] and both[0] > both[2]
    # the scan not hearing "b" changes nothing for RP 0 beyond dropping b's own term
    only_a = g.loglik(_scans({"a": -50.0}))[0]
    d = g.dense_
    p = g.detect_p_[0, 0]
    var = max(np.nan_to_num(d.var_db2[0, 0], nan=9.0), 9.0)
    expect = np.log(p) - 0.5 * np.log(2 * np.pi * var)          # v == mean: no squared term
    assert only_a[0] == pytest.approx(expect)


def test_knn_policy_not_heard_is_zero_powed():
    assert powed(np.array([np.nan, -100.0, -120.0, 0.0, -50.0])).tolist() == pytest.approx(
        [0, 0, 0, 1, 0.5 ** np.e])
    knn = WeightedKNN(1).fit(_tiny_db())
    assert knn.predict(_scans({"a": -50.0, "b": -80.0})).xy_m[0, 0] == pytest.approx(0.5)
    assert knn.predict(_scans({"c": -50.0})).xy_m[0, 0] == pytest.approx(20.5)


def test_sorensen_matches_brute_force():
    rng = np.random.default_rng(3)
    q = rng.random((6, 40)) * (rng.random((6, 40)) < 0.3)
    r = rng.random((9, 40)) * (rng.random((9, 40)) < 0.5)
    q[0] = 0
    ref = np.abs(q[:, None] - r[None]).sum(-1) / (q[:, None] + r[None]).sum(-1)
    ref[0] = 1.0
    assert np.allclose(sorensen_distances(q, r), ref)


def test_knn_positions_weights_and_order():
    d = np.array([[3.0, 1.0, 2.0, 9.0]])
    xy = np.array([[0.0, 0], [10, 0], [20, 0], [30, 0]])
    pos, score, nn = knn_positions(d, xy, k=2, power=1.0)
    assert nn.tolist() == [[1, 2]] and score.tolist() == [1.5]
    assert pos[0, 0] == pytest.approx((10 / 1 + 20 / 2) / (1 + 1 / 2))


def test_neighbour_smoothing_matches_brute_force():
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 12, (700, 2))
    nb = reference_neighbours(xy, sigma_m=1.0, chunk=128)   # several chunks
    d2 = ((xy[:, None] - xy[None]) ** 2).sum(-1)
    w = np.where(d2 <= 2.5 ** 2, np.exp(-d2 / 2.0), 0.0)
    w /= w.sum(axis=1, keepdims=True)
    dist = rng.random((4, len(xy)))
    assert np.allclose(np.add.reduceat(nb.weights, nb.indptr[:-1]), 1.0)
    assert np.allclose(smoothed_distances(dist, nb, 0.3), 0.7 * dist + 0.3 * dist @ w.T)
    assert np.array_equal(smoothed_distances(dist, nb, 0.0), dist)


def test_neighbour_smoothing_prefers_a_consistent_neighbourhood():
    # reference points every metre on a line; one isolated lucky match at x = 15 m, a whole
    # neighbourhood that matches almost as well around x = 4 m
    xy = np.column_stack([np.arange(21.0), np.zeros(21)])
    dist = np.full((1, 21), 0.6)
    dist[0, 15] = 0.2
    dist[0, 2:7] = 0.25
    assert knn_positions(dist, xy, 1)[0][0, 0] == 15.0
    smooth = smoothed_distances(dist, reference_neighbours(xy, 1.0), 0.5)
    assert knn_positions(smooth, xy, 1)[0][0, 0] == 4.0


def test_gaussian_loglik_is_the_sum_of_independent_terms():
    mean = np.array([[-60.0, np.nan]])
    var = np.array([[16.0, np.nan]])
    p = np.array([[0.8, 0.1]])
    ll = gaussian_loglik(np.array([[-62.0, -70.0]]), mean, var, p, var_floor_db2=9.0,
                         missing_mean_dbm=-95.0, missing_var_db2=49.0)
    expect = (np.log(0.8) - 0.5 * np.log(2 * np.pi * 16) - 4 / 32
              + np.log(0.1) - 0.5 * np.log(2 * np.pi * 49) - 625 / 98)
    assert ll[0, 0] == pytest.approx(expect)


def test_bad_parameters_and_unfitted_use():
    with pytest.raises(FingerprintError, match="not fitted"):
        WeightedKNN().predict(_scans({"a": -50.0}))
    with pytest.raises(FingerprintError, match="Sorensen distance needs the powed"):
        WeightedKNN(representation="dbm")
    with pytest.raises(FingerprintError, match="k must be >= 1"):
        GaussianMatch(0)
    with pytest.raises(FingerprintError, match="neighbour_mix must lie in"):
        WeightedKNN(neighbour_mix=1.5)
