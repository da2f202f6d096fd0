"""The demo's pure helpers: test-stand scenarios, hardware identity, the sample-clock copy."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from es_bringup.demo_calibration import (
    characterisation_scenario,
    daq_clock_copy,
    hardware_signature,
)
from es_msgs_py.bag import read_bag, write_array_bag
from es_msgs_py.topics import COMMAND, DISPLACEMENT, HEAT_LOAD, TEMPERATURE_RAW
from es_sim_plant.scenario import load_scenario, resolve_scenario


def test_characterisation_measures_the_hardware_of_its_scenario(tmp_path: Path) -> None:
    path = characterisation_scenario("thesis_ac", tmp_path)
    stand, source = load_scenario(str(path)), load_scenario("thesis_ac")
    assert stand.excitation is not None and stand.setpoint.sine_amplitude == 0.0
    assert (stand.rows, stand.cols, stand.seed) == (source.rows, source.cols, source.seed)
    assert stand.actuators == source.actuators
    # thermal set-up of the scenario, test-stand program (temperature ramp) of characterisation
    assert stand.thermal == source.thermal
    assert stand.base == load_scenario("characterisation").base
    with_effect = characterisation_scenario("thesis_ac", tmp_path, {"delay": True}, suffix="_d")
    assert load_scenario(str(with_effect)).effects.enabled_names() == ["delay"]


def _thesis_ac_copy(tmp_path: Path, name: str, **changes: object) -> str:
    import yaml

    data = yaml.safe_load(Path(str(resolve_scenario("thesis_ac"))).read_text())
    data.update(changes, name=name)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_seed_tells_hardware_apart_only_with_spread(tmp_path: Path) -> None:
    ac = hardware_signature(characterisation_scenario("thesis_ac", tmp_path))
    dc_ac = hardware_signature(characterisation_scenario("thesis_dc_ac", tmp_path))
    mirror = hardware_signature(characterisation_scenario("dm_exposure", tmp_path))
    assert ac == dc_ac  # the thesis's one sample: same seed, spread, sensor and lag
    assert mirror != ac
    other_sample = _thesis_ac_copy(tmp_path, "other_sample", seed=12)
    assert hardware_signature(characterisation_scenario(other_sample, tmp_path)) != ac
    no_spread: dict[str, dict[str, float]] = {"spread": {}}
    ideal_11 = _thesis_ac_copy(tmp_path, "ideal_11", actuators=no_spread)
    ideal_12 = _thesis_ac_copy(tmp_path, "ideal_12", actuators=no_spread, seed=12)
    assert hardware_signature(
        characterisation_scenario(ideal_11, tmp_path)
    ) == hardware_signature(characterisation_scenario(ideal_12, tmp_path))  # seeds draw noise


def test_thesis_scenarios_run_the_default_simulator() -> None:
    for name in ("thesis_ac", "thesis_dc_ac"):
        sc = load_scenario(name)
        assert sc.actuators.spread and sc.sensors.noise_sd > 0
        assert sc.effects.sensor_lag.enabled
        # a lag of seconds, physical, scaled with the scenario like its thermal constants
        assert load_scenario(name, 1.0).effects.sensor_lag.tau_s >= 1.0
        assert sc.effects.sensor_lag.tau_s == sc.time_scale * load_scenario(
            name, 1.0
        ).effects.sensor_lag.tau_s


def test_thermal_node_undoes_the_known_sensor_lag_once() -> None:
    from es_bringup.bringup import scenario_parameters

    thermal, feedforward = scenario_parameters("thesis_ac", {})
    assert thermal["sensor_lag_tau"] == load_scenario("thesis_ac", 1.0).effects.sensor_lag.tau_s
    assert feedforward["compensation.temperature_lead_s"] == 0.0  # not a second time
    thermal, feedforward = scenario_parameters("thesis_ac", {"effects.sensor_lag": False})
    assert "sensor_lag_tau" not in thermal
    assert feedforward["compensation.temperature_lead_s"] == 0.0  # no calibrated lead given
    _, feedforward = scenario_parameters(
        "thesis_ac", {"effects.sensor_lag": False}, {"compensation.temperature_lead_s": 2.0}
    )
    assert feedforward["compensation.temperature_lead_s"] == 2.0  # the calibrated one
    thermal, _ = scenario_parameters("dm_exposure", {})
    assert "sensor_lag_tau" not in thermal  # its scenario has no lag


def test_sample_clock_copy_restamps_by_index(tmp_path: Path) -> None:
    stand = characterisation_scenario("thesis_ac", tmp_path)
    steps, every = 50, 25  # characterisation: 250 Hz control, 10 Hz sensors
    clumped = np.repeat(np.arange(steps // 5) * 0.02, 5)  # a lagging recorder's stamps
    grid = np.random.default_rng(0).normal(size=(steps, 1, 1))
    write_array_bag(
        tmp_path / "bag",
        {
            COMMAND: (clumped, grid),
            DISPLACEMENT: (clumped, grid),
            HEAT_LOAD: (np.zeros(2), np.zeros((2, 1, 1))),
            TEMPERATURE_RAW: (np.zeros(2), np.full((2, 1), 40.0)),
        },
    )
    copy = read_bag(daq_clock_copy(tmp_path / "bag", tmp_path / "daq", str(stand)))
    np.testing.assert_allclose(copy[COMMAND].times, np.arange(steps) / 250.0)
    np.testing.assert_allclose(copy[TEMPERATURE_RAW].times, [0.0, every / 250.0])
    got = copy[DISPLACEMENT].values
    assert got is not None
    np.testing.assert_array_equal(got, grid)


def test_parameters_file_follows_the_graph_into_its_namespace(tmp_path: Path) -> None:
    import yaml

    from es_bringup.bringup import GraphConfig, namespaced_params_file

    source = tmp_path / "params.yaml"
    source.write_text(yaml.safe_dump({"feedforward": {"ros__parameters": {"rows": 2}}}))
    config = GraphConfig(scenario="thesis_ac", log_dir=tmp_path / "logs", namespace="run0")
    copy = yaml.safe_load(namespaced_params_file(source, "feedforward", config).read_text())
    assert copy == {"/run0/feedforward": {"ros__parameters": {"rows": 2}}}
