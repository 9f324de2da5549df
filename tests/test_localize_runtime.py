"""The localizer runtime at work depends on numpy and pyarrow only (issue #7): opening a site's
bundles, choosing the floor, locating scans and localizing a walk import no pandas, scipy or
scikit-learn. (pyarrow's own conversions would import pandas: ``localize.arrow_numpy``.)"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pytest
from radio_fixtures import SITE, built  # noqa: F401  (fixture)

from localize.arrow_numpy import numeric_column

CHILD = """
import json, sys
import numpy as np
from localize.baselines import make_localizer
from localize.floors import SiteMaps
from localize.steps import RadioScan, StepSummaries
from localize.walk_radio import walk_radio

a = np.load(sys.argv[2], allow_pickle=False)
meta = json.loads(sys.argv[3])
cut = np.cumsum(a["scan_len"])[:-1]
scans = [None] * len(a["t_ms"])
for slot, t, keys, rssi in zip(a["scan_slot"], a["scan_t"], np.split(a["scan_keys"], cut),
                               np.split(a["scan_rssi"], cut)):
    scans[int(slot)] = RadioScan(int(t), keys, rssi)
cols = ("t_ms", "frequency_hz", "delta_acc_ms2", "compass_deg", "turn_deg", "strength_ut",
        "azimuth_deg", "polar_deg", "attitude", "relative_heading_deg")
steps = StepSummaries(**{c: a[c] for c in cols}, scans=tuple(scans), **meta)
maps = SiteMaps.open(sys.argv[1])
bundle = maps.select(steps, [], device_model="")
wr = walk_radio(bundle, "", steps, [])
for method in ("auto", "indoormap", "align"):
    track = make_localizer(method, bundle, radio=wr.radio, rng=7).run(wr.steps)
    assert np.isfinite(track.x_m).all() and len(track.x_m) == len(steps)
print(json.dumps({"floor": bundle.manifest["floor_name"], "modules": sorted(
    m for m in sys.modules if m.split(".")[0] in ("pandas", "scipy", "sklearn", "shapely"))}))
"""


def test_localizing_a_walk_imports_no_pandas_scipy_sklearn(built, tmp_path):  # noqa: F811
    from survey.step_summaries import step_summaries
    from survey.trace_reader import read_trace

    site = json.loads((SITE / "truth" / "site.json").read_text())
    walk = next(w for w in site["walks"] if w["floor"] == "F2")
    steps = step_summaries(read_trace(SITE / walk["trace_path"]))
    slots = [i for i, s in enumerate(steps.scans) if s is not None]
    assert slots, "the sample walk has Wi-Fi scans"
    np.savez(tmp_path / "walk.npz", **{c: getattr(steps, c) for c in (
        "t_ms", "frequency_hz", "delta_acc_ms2", "compass_deg", "turn_deg", "strength_ut",
        "azimuth_deg", "polar_deg", "attitude", "relative_heading_deg")},
        scan_slot=np.array(slots), scan_t=np.array([steps.scans[i].t_ms for i in slots]),
        scan_len=np.array([len(steps.scans[i]) for i in slots]),
        scan_keys=np.concatenate([steps.scans[i].keys for i in slots]),
        scan_rssi=np.concatenate([steps.scans[i].rssi_dbm for i in slots]))
    meta = {k: getattr(steps, k) for k in ("trace_id", "site_id", "floor_id", "floor_name")}
    out = subprocess.run([sys.executable, "-c", CHILD, str(built), str(tmp_path / "walk.npz"),
                          json.dumps(meta)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["floor"] == "F2"
    assert result["modules"] == [], f"the runtime pulled in {result['modules']}"


@pytest.mark.parametrize("typ", [pa.int64(), pa.int32(), pa.uint8(), pa.float64(),
                                 pa.float32()])
def test_numeric_column_matches_to_numpy(typ):
    values = [3, None, 7, 1, None, 250]
    chunked = pa.chunked_array([pa.array(values[:2], typ), pa.array([], typ),
                                pa.array(values[2:], typ)])
    got = numeric_column(chunked)
    assert got.dtype == np.float64  # nulls: float with NaN, as to_numpy
    np.testing.assert_array_equal(got, chunked.to_numpy())
    plain = pa.chunked_array([pa.array([5, 6, 7, 8, 9], typ)]).chunk(0).slice(1, 3)
    got = numeric_column(plain)  # a slice: the buffer's offset is honoured, the type kept
    np.testing.assert_array_equal(got, [6, 7, 8])
    assert got.dtype == plain.to_numpy().dtype
    only_some = pa.chunked_array([pa.array([1, 2], typ), pa.array([None, 4], typ)])
    np.testing.assert_array_equal(numeric_column(only_some), [1, 2, np.nan, 4])
    assert numeric_column(pa.chunked_array([], typ)).shape == (0,)


def test_numeric_column_refuses_text():
    with pytest.raises(TypeError, match="not a numeric"):
        numeric_column(pa.chunked_array([pa.array(["a"])]))


def test_bundle_tables_read_without_pandas(built):  # noqa: F811
    """Every table of the site bundle (the floor models: not checked at load, read when
    asked) and of a floor bundle."""
    code = ("import sys\nfrom localize.bundle import load_bundle\n"
            f"for name in ('_site', 'F1'):\n    b = load_bundle({str(built)!r} + '/' + name)\n"
            "    n = [b.table(t).num_rows for t in b.manifest['tables']]\n"
            "    assert sum(n) > 0, n\n"
            "print('pandas' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"
