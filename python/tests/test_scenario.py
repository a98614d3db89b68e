"""Scenarios: loading, editing with --set's checks, and the keyed error."""

import pytest

import cqnet


def test_builtins_load_and_round_trip_through_toml():
    for name in ["default", "sensor-selection", "random-exchange", "location", "compressive"]:
        s = cqnet.Scenario.builtin(name)
        assert cqnet.Scenario.from_toml(s.to_toml()) == s
    assert cqnet.Scenario.default().get("quantizer.bits") == 8
    assert cqnet.Scenario.builtin("sensor-selection").get("sensors.max_active_total") == 18
    with pytest.raises(ValueError, match="sensor-selection"):
        cqnet.Scenario.builtin("no-such-scenario")


def test_set_changes_a_value_and_chains():
    s = cqnet.Scenario.default().set("filter.particles", 500).set("quantizer.bits", 4)
    assert s.get("filter.particles") == 500
    assert s.get("quantizer.bits") == 4
    assert "particles = 500" in s.to_toml()


@pytest.mark.parametrize(
    "key, value, words",
    [
        ("filter.particles", -5, "expected u32"),
        ("filter.particles", "many", "filter.particles"),
        ("quantizer.bits", 0, "quantizer.bits"),
        ("filter.particle", 5, "no key `particle`"),
        ("nope.x", 1, "no section `nope`"),
    ],
)
def test_a_bad_set_raises_the_keyed_error_and_changes_nothing(key, value, words):
    s = cqnet.Scenario.default()
    before = s.to_toml()
    with pytest.raises(cqnet.ScenarioError) as raised:
        s.set(key, value)
    assert raised.value.key == key
    assert words in str(raised.value)
    assert isinstance(raised.value, cqnet.CqnetError)
    assert s.to_toml() == before


def test_the_error_is_the_same_as_the_command_lines(cqnet_bin, tmp_out):
    import subprocess

    with pytest.raises(cqnet.ScenarioError) as raised:
        cqnet.Scenario.default().set("filter.particles", -5)
    cli = subprocess.run(
        [str(cqnet_bin), "sim", "--set", "filter.particles=-5", "--out", str(tmp_out)],
        capture_output=True,
        text=True,
    )
    assert cli.returncode != 0
    assert str(raised.value) in cli.stderr


def test_values_valid_only_together_go_in_one_update():
    with pytest.raises(cqnet.ScenarioError) as raised:
        cqnet.Scenario.default().set("nodes.grid", [2, 1])
    assert raised.value.key == "fusion_graph.radius"
    s = cqnet.Scenario.default().update({"nodes.grid": [2, 1], "fusion_graph.radius": 800.0})
    assert s.edges() == [(0, 1)]


def test_faults_are_checked_as_in_a_file():
    s = cqnet.Scenario.default()
    ok = s.with_faults([{"kind": "kill", "actor": "node-4", "at_step": 10, "signal": "SIGKILL"}])
    assert ok.get("faults")[0]["actor"] == "node-4"
    with pytest.raises(cqnet.ScenarioError) as raised:
        s.with_faults([{"kind": "kill", "actor": "node-44", "at_step": 10, "signal": "SIGKILL"}])
    assert "node-44" in str(raised.value)


def test_a_missing_file_is_a_scenario_error(tmp_out):
    with pytest.raises(cqnet.ScenarioError, match="cannot read"):
        cqnet.Scenario.from_file(tmp_out / "nothing.toml")


def test_the_scenario_gives_the_bounds_its_models():
    s = cqnet.Scenario.default()
    sensors = s.sensors()
    assert len(sensors) == 225 == s.sensor_positions().shape[0]
    assert sensors[0].law["kind"] == "bearing"
    assert sensors[0].quantizer.bits == 8
    assert s.prior_covariance()[0, 0] == 50.0**2
    assert s.dynamics().q.shape == (4, 4)
