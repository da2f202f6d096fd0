"""The demo's pure helpers: test-stand scenarios, hardware identity, the sample-clock copy."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from es_msgs_py.bag import read_bag, write_array_bag
from es_msgs_py.topics import COMMAND, DISPLACEMENT, HEAT_LOAD, TEMPERATURE_RAW
from es_sim_plant.demo import _hardware_signature, characterisation_scenario, daq_clock_copy
from es_sim_plant.scenario import load_scenario


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


def test_seed_tells_hardware_apart_only_with_spread(tmp_path: Path) -> None:
    ac = _hardware_signature(characterisation_scenario("thesis_ac", tmp_path))
    dc_ac = _hardware_signature(characterisation_scenario("thesis_dc_ac", tmp_path))
    mirror = _hardware_signature(characterisation_scenario("dm_exposure", tmp_path))
    assert ac == dc_ac  # same actuator, no spread: the seeds draw only noise
    assert mirror != ac


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
    np.testing.assert_array_equal(copy[DISPLACEMENT].values, grid)


def test_parameters_file_follows_the_graph_into_its_namespace(tmp_path: Path) -> None:
    import yaml

    from es_sim_plant.bringup import GraphConfig, namespaced_params_file

    source = tmp_path / "params.yaml"
    source.write_text(yaml.safe_dump({"feedforward": {"ros__parameters": {"rows": 2}}}))
    config = GraphConfig(scenario="thesis_ac", log_dir=tmp_path / "logs", namespace="run0")
    copy = yaml.safe_load(namespaced_params_file(source, "feedforward", config).read_text())
    assert copy == {"/run0/feedforward": {"ros__parameters": {"rows": 2}}}
