"""Review of the BLE floor model (site bundle tables, SiteMaps.choose, ``floor --kind``).

- A site bundle whose floor model tables are incomplete (coef without intercept) or that
  announces a model in ``metrics`` without its tables loaded without the model, silently: a
  walk's floor then came from the other model, or the error blamed an old build.
- A malformed ``ble_floor_*`` table was reported as ``floor_coef``/``floor_intercept``, without
  the bundle's path.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pyarrow as pa
import pytest
from click.testing import CliRunner

from localize.bundle import load_bundle
from localize.errors import LocalizationError
from localize.floors import SiteMaps
from mapping.bundle_writer import BundleContent, write_bundle
from survey.cli import main

from radio_fixtures import SITE

F2_WALKS = sorted((SITE / "F2" / "path_data_files").glob("*.txt.gz"))


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("floor_ble_review") / "bundles"
    res = CliRunner().invoke(main, ["build", str(SITE), "-o", str(out)])
    assert res.exit_code == 0, res.output
    return out


def _with_site(built: Path, target: Path, content: BundleContent | None = None, *,
               drop=(), replace=None, metrics_drop=()) -> Path:
    """The floor bundles of ``built`` beside ``content`` (or ``built``'s site bundle with
    tables dropped or replaced, metrics dropped) as ``_site``."""
    for floor in ("F1", "F2"):
        shutil.copytree(built / floor, target / floor)
    if content is None:
        site = load_bundle(built / "_site")
        m = site.manifest
        tables = {n: site.table(n) for n in m["tables"] if n not in drop}
        tables.update(replace or {})
        content = BundleContent(site_id=m["site_id"], floor_id="", floor_name="", kind="site",
                                tables=tables, build=m["build"],
                                metrics={k: v for k, v in m["metrics"].items()
                                         if k not in metrics_drop})
    write_bundle(target / "_site", content)
    return target


@pytest.mark.parametrize("drop,metrics_drop,names", [
    (("ble_floor_intercept",), (), ("ble_floor_coef", "ble_floor_intercept")),
    (("ble_floor_coef", "ble_floor_intercept", "ble_floor_meta"), (),
     ("ble_floor_model", "ble_floor_coef")),
    (("floor_intercept",), (), ("floor_coef", "floor_intercept")),
    ((), ("ble_floor_model",), ("ble_floor_model", "ble_floor_coef")),
])
def test_an_incomplete_floor_model_in_a_site_bundle_is_refused(built, tmp_path, drop,
                                                                metrics_drop, names):
    out = _with_site(built, tmp_path / "b", drop=drop, metrics_drop=metrics_drop)
    with pytest.raises(LocalizationError) as err:
        SiteMaps.open(out)
    msg = str(err.value)
    assert str(out / "_site") in msg and all(n in msg for n in names), msg
    res = CliRunner().invoke(main, ["floor", str(out), str(F2_WALKS[0])])
    assert res.exit_code != 0 and str(out / "_site") in res.output


def test_a_malformed_ble_floor_table_is_named(built, tmp_path):
    site = load_bundle(built / "_site")
    coef = site.table("ble_floor_coef").rename_columns(["ap", "floor", "weight"])
    out = _with_site(built, tmp_path / "a", replace={"ble_floor_coef": coef})
    with pytest.raises(LocalizationError, match=r"table 'ble_floor_coef' lacks columns "
                                                r"\['coef'\]") as err:
        SiteMaps.open(out)
    assert str(out / "_site") in str(err.value)
    icpt = site.table("ble_floor_intercept")
    other = pa.table({"floor": ["F1", "F9"], "intercept": icpt.column("intercept")})
    out = _with_site(built, tmp_path / "b", replace={"ble_floor_intercept": other})
    with pytest.raises(LocalizationError, match="ble_floor_coef names floors that "
                                                "ble_floor_intercept lacks"):
        SiteMaps.open(out)
    text = pa.table({"ap": coef.column("ap"), "floor": coef.column("floor"),
                     "coef": pa.array(["x"] * len(coef))})
    out = _with_site(built, tmp_path / "c", replace={"ble_floor_coef": text})
    with pytest.raises(LocalizationError, match="ble_floor_coef"):
        SiteMaps.open(out)
