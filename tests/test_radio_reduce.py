"""The radio build reduces walk by walk (bounded memory, docs/reliability.md): the running
aggregates equal a whole-table group-by whatever the batches, the reducers hold keys and never
rows, the results do not depend on the walks' order, and the row samples of the device fit and
the floor model are capped, deterministic and still good enough."""

from __future__ import annotations

import hashlib

import numpy as np
import pandas as pd
import pytest
from radio_fixtures import device_of, sample_store, sample_truth, wifi_obs  # noqa: F401
from test_ap_selection import _survey

from mapping.ap_selection import APEvidence, APSelectionParams, select_aps
from mapping.fingerprints import FingerprintSums, build_fingerprints
from mapping.radio_build import (
    RadioParams,
    build_site_radio,
    site_observations,
    site_radio,
)
from mapping.radio_reduce import KeyedAggregate, capped_walk_sample, walk_rows
from survey.store import SurveyStore


@pytest.mark.parametrize("compact_rows", [1, 7, 10**6])
def test_keyed_aggregate_equals_a_group_by(compact_rows):
    rng = np.random.default_rng(3)
    keys = rng.integers(-5, 40, 500)
    s, n = rng.normal(size=500), rng.integers(0, 9, 500)
    agg = KeyedAggregate(("s", "n"), compact_rows=compact_rows)
    for part in np.array_split(np.arange(500), 13):
        agg.add(keys[part], s=s[part], n=n[part])
    got_keys, got = agg.result()
    want = pd.DataFrame({"k": keys, "s": s, "n": n}).groupby("k").sum()
    assert got_keys.tolist() == want.index.tolist()
    assert np.allclose(got["s"], want["s"], atol=1e-12)
    assert got["n"].dtype.kind == "i" and got["n"].tolist() == want["n"].tolist()
    assert KeyedAggregate(("s",)).result()[0].size == 0


def test_capped_walk_sample_is_deterministic_and_capped():
    sizes = pd.Series({f"w{i}": 100 + 37 * i for i in range(30)})
    assert capped_walk_sample(sizes, 10**6) == set(sizes.index)  # everything fits
    chosen = capped_walk_sample(sizes, 2000, seed=1)
    assert chosen == capped_walk_sample(sizes.iloc[::-1], 2000, seed=1)  # any order
    assert chosen != capped_walk_sample(sizes, 2000, seed=2)
    # a prefix of the walks by priority that reaches the cap, not one walk more
    prio = {w: hashlib.sha256(f"1:{w}".encode()).hexdigest() for w in sizes.index}
    ordered = sorted(sizes.index, key=prio.get)
    taken = ordered[:len(chosen)]
    assert set(taken) == chosen
    assert sizes[taken].sum() >= 2000 and sizes[taken[:-1]].sum() < 2000


def _fingerprints(obs: pd.DataFrame, walks: list, compact_rows: int):
    sums = FingerprintSums(kind="wifi", cell_m=2.0, max_age_ms=3000, compact_rows=compact_rows)
    for rows in walks:
        sums.add(obs.iloc[rows])
    return sums.result()


def test_fingerprints_walk_by_walk_equal_the_whole_table(wifi_obs):  # noqa: F811
    obs = wifi_obs["F1"]
    whole = build_fingerprints(obs, cell_m=2.0, max_age_ms=3000)
    walks = walk_rows(obs)
    for got in (_fingerprints(obs, walks[::-1], 50), _fingerprints(obs, walks, 10**6)):
        pd.testing.assert_frame_equal(got.rp, whole.rp, rtol=1e-12)
        pd.testing.assert_frame_equal(got.fp, whole.fp, rtol=1e-9)
        assert got.fp["var_db2"].notna().sum() > 100


def _copies(obs: pd.DataFrame, n: int) -> pd.DataFrame:
    """``n`` copies of every walk, as different walks (trace and scan ids)."""
    step = int(obs["scan_id"].max()) + 1
    return pd.concat([obs.assign(trace_id=obs["trace_id"].astype(str) + f"#{k}",
                                 scan_id=obs["scan_id"] + k * step) for k in range(n)],
                     ignore_index=True)


def test_reducers_hold_keys_not_rows(wifi_obs):  # noqa: F811
    """Three times the walks: the same keys held, counts tripled, means unchanged."""
    obs = wifi_obs["F2"]
    once, thrice = (_fingerprints(o, walk_rows(o), 100) for o in (obs, _copies(obs, 3)))
    assert len(thrice.rp) == len(once.rp) and len(thrice.fp) == len(once.fp)
    assert (thrice.fp["n"].to_numpy() == 3 * once.fp["n"].to_numpy()).all()
    assert np.allclose(thrice.fp["mean_dbm"], once.fp["mean_dbm"], atol=1e-9)
    held = []
    for o in (obs, _copies(obs, 3)):
        ev = APEvidence()
        for rows in walk_rows(o):
            ev.add_walk(o.iloc[rows].assign(floor="F2"), floor_column="floor")
        held.append([len(agg.result()[0]) for agg in (ev._per_ap, ev._change, ev._day_cell)])
    assert held[0] == held[1]


def test_ap_selection_does_not_depend_on_walk_order_or_batches():
    obs, ssid = _survey()
    want = select_aps(obs, ssid=ssid, floor_column="floor", floor_order=["F1", "F2", "F3", "F4"])
    assert len(want.dropped) >= 6
    ev = APEvidence(APSelectionParams(), compact_rows=5)
    for rows in walk_rows(obs)[::-1]:
        ev.add_walk(obs.iloc[rows], floor_column="floor")
    got = ev.select(ssid=ssid, floor_order=["F1", "F2", "F3", "F4"])
    assert got.kept.tolist() == want.kept.tolist()
    pd.testing.assert_frame_equal(got.dropped, want.dropped)


def test_store_walks_and_tables_in_memory_give_the_same_maps(sample_store, device_of):  # noqa: F811
    st = SurveyStore.open(sample_store)
    built = build_site_radio(st, ["F1", "F2"])
    obs = {k: site_observations(st, None, ["F1", "F2"], k) for k in ("wifi", "ble")}
    again = site_radio(obs, pd.Series(device_of), ["F1", "F2"])
    pd.testing.assert_frame_equal(built.devices, again.devices)
    assert sorted(built.fingerprints) == sorted(again.fingerprints)
    for key, db in built.fingerprints.items():
        pd.testing.assert_frame_equal(db.fp, again.fingerprints[key].fp, rtol=1e-9)
    for kind, sel in built.selections.items():
        assert sel.kept.tolist() == again.selections[kind].kept.tolist()
    assert np.allclose(built.floor_model.coef, again.floor_model.coef)


def test_capped_samples_keep_the_device_fit_and_the_floor_model(wifi_obs, device_of,  # noqa: F811
                                                                 sample_truth):  # noqa: F811
    parts, offset = [], 0
    for floor, o in wifi_obs.items():
        parts.append(o.assign(floor=floor, scan_id=o["scan_id"] + offset, ssid=""))
        offset += int(o["scan_id"].max()) + 1
    obs = {"wifi": pd.concat(parts, ignore_index=True)}
    full = site_radio(obs, pd.Series(device_of), ["F1", "F2"])
    rows_per_walk = obs["wifi"].groupby("trace_id").size()
    cap = int(rows_per_walk.sum() / 3)
    capped = site_radio(obs, pd.Series(device_of), ["F1", "F2"],
                        params=RadioParams(calibration_max_rows=cap, floor_model_max_rows=cap // 2))
    dev = next(d for d in sample_truth["devices"] if not d["reference"])
    k_true = 1.0 / dev["rssi_k"]
    for table in (full.devices, capped.devices):
        row = table.set_index("device_model").loc[dev["model"]]
        assert row["method"] == "offline" and abs(row["k"] - k_true) < 0.05
    assert full.devices["n_pairs"].sum() > capped.devices["n_pairs"].sum()
    n_walks = obs["wifi"]["trace_id"].nunique()
    assert full.floor_model.meta["n_walks"] == n_walks
    assert 2 <= capped.floor_model.meta["n_walks"] < n_walks
    assert capped.floor_model.meta["cv_scan_accuracy"] >= 0.95


def test_rows_without_ids_or_rssi_are_left_out():
    """A walk whose RSSI is all NaN, rows without a transmitter or a floor: selected as if
    those rows were not there."""
    obs, ssid = _survey()
    args = {"ssid": ssid, "floor_column": "floor", "floor_order": ["F1", "F2", "F3", "F4"]}
    want = select_aps(obs, **args)
    w1 = obs[obs["trace_id"] == "w1F1"].iloc[:60]  # without the rare transmitter
    bad = w1.assign(trace_id="nan-walk", scan_id=w1["scan_id"] + 10**6, rssi_dbm=np.nan)
    no_ap = obs.iloc[:50].assign(ap=None)
    no_floor = w1.assign(floor=None, scan_id=w1["scan_id"] + 2 * 10**6, trace_id="no-floor")
    got = select_aps(pd.concat([obs, bad, no_ap, no_floor], ignore_index=True), **args)
    assert got.kept.tolist() == want.kept.tolist()
    assert got.dropped["reason"].tolist() == want.dropped["reason"].tolist()
    sums = FingerprintSums(kind="wifi", cell_m=2.0, max_age_ms=None)
    sums.add(pd.concat([obs, no_ap], ignore_index=True))
    assert "None" not in sums.result().fp["ap"].tolist()


def test_a_walk_on_two_floors_feeds_each_floor(wifi_obs, device_of):  # noqa: F811
    one, two = (o.assign(floor=f, ssid="") for f, o in wifi_obs.items())
    two = two.assign(scan_id=two["scan_id"] + int(one["scan_id"].max()) + 1)
    walk_a, walk_b = one["trace_id"].iloc[0], two["trace_id"].iloc[0]
    device = pd.Series(device_of)
    separate = site_radio({"wifi": pd.concat([one, two], ignore_index=True)}, device,
                          ["F1", "F2"], params=RadioParams(floor_model=False))
    merged = pd.concat([one, two.replace({"trace_id": {walk_b: walk_a}})], ignore_index=True)
    device[walk_a] = device[walk_b] = device[walk_a]
    joined = site_radio({"wifi": merged}, device, ["F1", "F2"],
                        params=RadioParams(floor_model=False, calibrate_devices=False))
    for floor in ("F1", "F2"):
        assert (joined.fingerprints[(floor, "wifi")].rp["n_scans"].sum()
                == separate.fingerprints[(floor, "wifi")].rp["n_scans"].sum())


def test_progress_ends_with_the_walks_read(sample_store):  # noqa: F811
    """The last progress line of each kind counts the walks read, so that a run does not seem
    to stop short ('read walk 100/102' was the last line of 102 walks)."""
    st = SurveyStore.open(sample_store)
    obs = {k: site_observations(st, None, ["F1", "F2"], k) for k in ("wifi", "ble")}
    obs["ble"] = obs["ble"][obs["ble"]["trace_id"] != obs["ble"]["trace_id"].iloc[0]]
    device_of = st.traces(None).set_index("trace_id")["device_model"].fillna("").astype(str)
    said: list[str] = []
    site_radio(obs, device_of, ["F1", "F2"], progress=said.append)
    for kind in ("wifi", "ble"):
        assert f"{kind}: read {obs[kind]['trace_id'].nunique()} walks" in said
