"""Closed loop on the plant core: compensation of an effect against the run without it.

The calibration loop's goal (``bench/bench_calibration_loop.py``) in small: the thesis
actuator on the shortened ``thesis_ac`` stand at 50 Hz, the set point of ``thesis_dc_ac``
(100 nm DC + 25 nm, clear of the 0 V floor), the feedforward (inverse_hyperbolic) with the
plant's true parameters and the effect's true compensation, fed the raw sensor temperature.
Its RMS tracking error must stay within 1.5x of the same loop without the effect.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from es_bringup.demo_calibration import LOOP_SCENARIO, scenario_with_effects
from es_feedforward.compensation import CompensationParams
from es_feedforward.feedforward import Feedforward, FeedforwardConfig, Mode
from es_sim_plant.plant import Observation, Plant, simulate
from es_sim_plant.scenario import load_scenario, resolve_scenario

#: The scenario's sensor lag [s] at its time scale (5 s physical x 0.02) and the plant's
#: expansion (its default alpha, zero at the run's initial base temperature).
CASES: dict[str, tuple[dict[str, Any], dict[str, float]]] = {
    "sensor_lag": (
        {"sensor_lag": {"enabled": True, "tau_s": 5.0}},
        {"temperature_lead_s": 0.1, "temperature_lead_filter_s": 0.05},
    ),
    "thermal_expansion": (
        {"thermal_expansion": {"enabled": True, "alpha_m_per_degc": 4e-10}},
        {"thermal_expansion": 4e-10, "expansion_reference_temperature": 40.0},
    ),
}


def _rms_error(tmp_path: Path, effects: dict[str, Any], compensation: dict[str, float]) -> float:
    suffix = "_" + "_".join(effects) if effects else "_none"
    path = scenario_with_effects(LOOP_SCENARIO, tmp_path, effects, suffix)
    data = yaml.safe_load(path.read_text())
    data["setpoint"] = yaml.safe_load(resolve_scenario("thesis_dc_ac").read_text())["setpoint"]
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    scenario = load_scenario(str(path)).with_overrides(control_rate=50.0)
    plant = Plant(scenario)
    core = Feedforward(
        FeedforwardConfig(
            scenario.shape,
            params=plant.true_params,
            mode=Mode.INVERSE_HYPERBOLIC,
            compensation=CompensationParams().replaced(compensation),
        )
    )

    def controller(observation: Observation) -> np.ndarray:
        if observation.temperature_raw is not None:
            T = observation.temperature_raw.reshape(scenario.shape)
            core.update_temperature(T, observation.time)
        return core.command(observation.setpoint, observation.time).voltage

    result = simulate(plant, controller=controller)
    skip = round(scenario.control_rate / scenario.setpoint.sine_frequency)
    error = (result.displacement - result.setpoint)[skip:]
    return float(np.sqrt(np.mean(error**2)))


@pytest.mark.parametrize("effect", sorted(CASES))
def test_compensated_effect_tracks_within_1_5x_of_no_effect(tmp_path: Path, effect: str) -> None:
    effects, compensation = CASES[effect]
    reference = _rms_error(tmp_path, {}, {})
    uncompensated = _rms_error(tmp_path, effects, {})
    compensated = _rms_error(tmp_path, effects, compensation)
    assert uncompensated > 2.0 * reference  # the effect matters
    assert compensated <= 1.5 * reference
