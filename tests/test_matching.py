"""Matchers: accuracy on the simulated site, the stated missing-AP policy, kernels."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from radio_fixtures import sample_store, split_walks, walk_ids, wifi_obs  # noqa: F401

from localize.radio_match import (
    ReferenceMotion,
    WalkSmoothing,
    gaussian_loglik,
    knn_positions,
    powed,
    reference_neighbours,
    smoothed_distances,
    sorensen_distances,
    walk_scores,
)
from mapping.errors import FingerprintError
from mapping.fingerprints import build_fingerprints
from mapping.matching import (
    GaussianMatch,
    WeightedKNN,
    default_matcher,
    default_walk_matcher,
)
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


def test_walk_matching_beats_scan_by_scan_on_the_simulated_site(wifi_obs):
    """Median 3.13 / 2.02 m (F1 / F2) against 3.25 / 2.08 scan by scan when written; p80
    8.8 -> 9.2 m on F1 (3.45 -> 3.48 on F2): the simulated walks are short and few."""
    for floor in ("F1", "F2"):
        scan = _lowo(wifi_obs[floor], default_matcher())
        walk = _lowo(wifi_obs[floor], default_walk_matcher())
        assert np.isfinite(walk).all()
        assert np.median(walk) < np.median(scan)
        assert np.percentile(walk, 80) < 1.1 * np.percentile(scan, 80)


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


def test_knn_positions_pick_by_one_score_and_weigh_by_another():
    xy = np.array([[0.0, 0], [10, 0], [20, 0], [30, 0]])
    pick = np.array([[0.1, 0.2, 5.0, 5.0]])
    own = np.array([[0.5, 0.25, 0.1, 0.1]])
    pos, score, nn = knn_positions(pick, xy, k=2, power=1.0, weight_dist=own)
    assert nn.tolist() == [[0, 1]] and score[0] == pytest.approx(0.375)
    assert pos[0, 0] == pytest.approx(10 * 4 / (2 + 4))


def test_reference_motion_is_a_gaussian_transition():
    rng = np.random.default_rng(8)
    xy = rng.uniform(0, 30, (400, 2))
    motion = ReferenceMotion(xy)
    d2 = ((xy[:, None] - xy[None]) ** 2).sum(-1)
    w = np.where(d2 <= (2.5 * 2.0) ** 2, np.exp(-d2 / 8.0), 0.0)
    w /= w.sum(axis=1, keepdims=True)                 # w[i, j]: from i to j
    p, v = rng.random(400), rng.random(400)
    assert np.allclose(motion.forward(p, 2.0), p @ w)  # mass is carried, not created
    assert motion.forward(p, 2.0).sum() == pytest.approx(p.sum())
    assert np.allclose(motion.backward(v, 2.0), w @ v)
    assert motion.plan(1.9) == [2.0]
    steps = motion.plan(13.0)                          # wider than one level: several steps
    assert len(steps) == 5 and sum(s * s for s in steps) == pytest.approx(169, rel=0.15)


def _corridor_walk():
    """Reference points every metre on a 60 m line; a walk at 1 m/s from x = 10 m to 24 m,
    one scan a second, each scan matching its true place (distance 0.2, growing 0.05 per
    metre away, at most 0.9)."""
    xy = np.column_stack([np.arange(60.0), np.zeros(60)])
    truth = np.arange(10.0, 25.0)
    t_ms = 1000.0 * np.arange(len(truth))
    dist = np.minimum(0.2 + 0.05 * np.abs(xy[None, :, 0] - truth[:, None]), 0.9)
    return xy, truth, t_ms, dist


def test_walk_scores_resolve_ambiguous_scans_from_the_walk():
    xy, truth, t_ms, dist = _corridor_walk()
    # every scan also matches, a hair better, one decoy place in x >= 40 m, a different one
    # each time (what a lone scan cannot tell from its true place); one scan shares nothing
    rng = np.random.default_rng(1)
    dist[np.arange(len(truth)), 40 + rng.integers(0, 20, len(truth))] = 0.19
    dist[3, :] = 1.0
    ok = np.arange(len(truth)) != 3
    alone = knn_positions(dist, xy, 1)[0][:, 0]
    assert np.all(alone[ok] >= 40)                    # scan by scan: all at their decoys
    motion = ReferenceMotion(xy)
    both = walk_scores(dist, t_ms, motion, WalkSmoothing(speed_mps=1.5))
    got = knn_positions(both, xy, 1, weight_dist=dist)[0][:, 0]
    assert np.all(np.abs(got[ok] - truth[ok]) <= 1.0)
    fwd = walk_scores(dist, t_ms, motion, WalkSmoothing(speed_mps=1.5, direction="forward"))
    got_fwd = knn_positions(fwd, xy, 1, weight_dist=dist)[0][:, 0]
    assert got_fwd[0] >= 40                           # no past to lean on
    assert np.all(np.abs(got_fwd[5:] - truth[5:]) <= 1.0)
    # the scores do not depend on the order the scans come in
    order = rng.permutation(len(truth))
    shuffled = walk_scores(dist[order], t_ms[order], motion, WalkSmoothing(speed_mps=1.5))
    np.testing.assert_allclose(shuffled, both[order])


def test_walk_scores_long_gap_breaks_the_chain():
    xy, _, t_ms, dist = _corridor_walk()
    t_ms = t_ms.copy()
    t_ms[7:] += 60_000                                 # a minute without scans
    motion = ReferenceMotion(xy)
    params = WalkSmoothing(max_sigma_m=20.0)
    apart = walk_scores(dist, t_ms, motion, params)
    np.testing.assert_allclose(apart[:7], walk_scores(dist[:7], t_ms[:7], motion, params))
    np.testing.assert_allclose(apart[7:], walk_scores(dist[7:], t_ms[7:], motion, params))
    one = walk_scores(dist[:1], t_ms[:1], motion, params)
    np.testing.assert_array_equal(one, dist[:1])      # a lone scan keeps its distances
    # a likelihood so sharp it underflows away from the best match: still finite scores
    assert np.isfinite(walk_scores(dist, t_ms, motion, WalkSmoothing(tau=1e-4))).all()
    with pytest.raises(ValueError, match="direction"):
        WalkSmoothing(direction="backward")
    with pytest.raises(ValueError, match="tau"):
        WalkSmoothing(tau=0.0)


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
