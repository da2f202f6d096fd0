"""Where a closed-loop variation comes from: offline runs that take one error source away.

Pure (no rclpy). The plant core and the feedforward core run the same scenario offline
(``es_sim_plant.plant.simulate``), the feedforward fed the simulator's *true* actuator
temperature instead of the thermal node's estimate:

- calibrated parameters, true temperature: what the parameters alone leave;
- the simulator's true parameters, true temperature: the floor of the model and the
  scenario itself (set-point quantisation, the hold over a control step).

Compared with the closed-loop run, the difference is what the temperature estimate (sensor
noise, lag, the thermal model) adds.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from es_feedforward.feedforward import Feedforward, FeedforwardConfig
from es_sim_plant.metrics import AlignedRun, RunMetrics, run_metrics
from es_sim_plant.plant import Observation, Plant, simulate
from es_sim_plant.scenario import Scenario


def offline_metrics(
    scenario: Scenario, config: FeedforwardConfig, period_s: float, true_params: bool = False
) -> RunMetrics:
    """Run ``scenario`` offline with the feedforward on the true actuator temperature.

    Args:
        scenario: the scenario (overrides already applied).
        config: the feedforward configuration (e.g. read from the calibrated YAML).
        period_s: set-point period for the variation, s.
        true_params: replace the configuration's laws by the simulator's true parameters.

    """
    plant = Plant(scenario)
    # the true actuator temperature has no sensor lag to undo (as in the bring-up, where the
    # thermal node undoes it)
    config = replace(config, compensation=replace(config.compensation, temperature_lead_s=0.0))
    if true_params:
        config = replace(config, params=plant.true_params)
    core = Feedforward(config)

    def controller(observation: Observation) -> np.ndarray:
        core.update_temperature(plant.actuator_temperature(), observation.time)
        return core.command(observation.setpoint, observation.time).voltage

    result = simulate(plant, controller=controller)
    steps = result.time.size
    flat = scenario.rows * scenario.cols
    run = AlignedRun(
        times=result.time + plant.dt,
        setpoint=result.setpoint.reshape(steps, flat),
        output=result.displacement.reshape(steps, flat),
        temperature=result.actuator_temperature.reshape(steps, flat),
        grid_shape=scenario.shape,
    )
    return run_metrics(run, period_s, skip_s=period_s)[0]
