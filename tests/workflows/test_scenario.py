"""One load_scenario for every scenario file (geoloc.workflows.scenario)."""

import pytest

from geoloc.analysis.errormodel import ErrorModel
from geoloc.assets import asset_path
from geoloc.workflows.flight import FlightScenario
from geoloc.workflows.limb_scenario import LimbScenario
from geoloc.workflows.rpc_scenario import RPCScenario
from geoloc.workflows.scenario import load_scenario

BUNDLED = {
    "qiao2017_table1.toml": ErrorModel,
    "qiao2017_table1_dem.toml": ErrorModel,
    "flight_scan.toml": FlightScenario,
    "tiangong2_limb.toml": LimbScenario,
    "zy3_nadir.toml": RPCScenario,
    "qiao2017_frame.toml": RPCScenario,
}


@pytest.mark.parametrize("name", sorted(BUNDLED))
def test_every_bundled_scenario_loads_as_its_kind(name):
    sc = load_scenario(asset_path("scenarios", name))
    assert type(sc) is BUNDLED[name]


def test_the_same_object_as_the_kinds_own_loader():
    # the dispatcher adds nothing: the [Q17] Table 1 budget equals ErrorModel.from_toml's
    path = asset_path("scenarios", "qiao2017_table1.toml")
    a, b = load_scenario(path), ErrorModel.from_toml(path)
    assert a.nominal == b.nominal and a.errors == b.errors and a.target_h_m == b.target_h_m


def test_a_verb_given_another_kind_says_what_the_file_is():
    with pytest.raises(
        ValueError,
        match=r"tiangong2_limb.toml: this is a limb-viewing orbit .*"
        r"kind = 'limb'\); expected kind 'montecarlo'",
    ):
        load_scenario(asset_path("scenarios", "tiangong2_limb.toml"), expect="montecarlo")


def test_explicit_kind_and_bad_kind(tmp_path):
    src = "\n".join(
        line
        for line in asset_path("scenarios", "tiangong2_limb.toml").read_text().splitlines()
        if not line.startswith("kind =")
    )
    f = tmp_path / "limb.toml"
    f.write_text(src)  # a kind-less file of the first phase: recognised by its tables
    assert isinstance(load_scenario(f, expect="limb"), LimbScenario)
    f.write_text('kind = "limb"\n' + src)
    assert isinstance(load_scenario(f, expect="limb"), LimbScenario)
    f.write_text('kind = "orbit"\n' + src)
    with pytest.raises(ValueError, match=r"kind = 'orbit' is not a scenario kind; known: \['flight_scan'"):
        load_scenario(f)
    g = tmp_path / "what.toml"
    g.write_text('name = "x"\n[pose]\nlat_deg = 1.0\n')
    with pytest.raises(ValueError, match=r"no 'kind' key, and its tables \['pose'\] are not those of a known"):
        load_scenario(g)
    with pytest.raises(FileNotFoundError):
        load_scenario(tmp_path / "missing.toml")
