"""Where a closed-loop variation comes from: offline runs that take one error source away.

Pure (no rclpy). The plant core and the feedforward core run the same scenario offline
(``es_sim_plant.plant.simulate``), the feedforward fed the simulator's *true* actuator
temperature instead of the thermal node's estimate:

- calibrated parameters, true temperature: what the parameters alone leave;
- the simulator's true parameters, true temperature: the floor of the model and the
  scenario itself (set-point quantisation, the hold over a control step).

Compared with the closed-loop run, the difference is what the temperature estimate (sensor
noise, lag, the thermal model) adds.

The thesis measured each temperature level of section 4-1 only once the stage had reached
equilibrium; :func:`settled_metrics` gives a run's figures over the periods clear of a
base-temperature step's transient, beside the strict figure over every period.
"""

from __future__ import annotations

from dataclasses import replace
from itertools import pairwise

import numpy as np

from es_bringup.metrics import AlignedRun, RunMetrics, run_metrics, whole_periods
from es_feedforward.feedforward import Feedforward, FeedforwardConfig
from es_sim_plant.plant import Observation, Plant, simulate
from es_sim_plant.scenario import Scenario

#: A step's transient lasts this many times the sum of the network's and the sensor's time
#: constants (e^-5 < 1 %: settled).
SETTLE_TIME_CONSTANTS = 5.0


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
    run = AlignedRun.of_simulation(result, plant.dt)
    return run_metrics(run, period_s, skip_s=period_s)[0]


def step_times(scenario: Scenario) -> list[float]:
    """Return the times at which the base temperature jumps (none for a linear profile), s."""
    base = scenario.base
    if base.interpolation != "step":
        return []
    points = list(zip(base.times, base.temperatures, strict=True))
    return [t for (_, before), (t, after) in pairwise(points) if after != before]


def settle_time(scenario: Scenario) -> float:
    """Return how long a base step's transient lasts in the scenario, s (simulation time).

    :data:`SETTLE_TIME_CONSTANTS` times the sum of the face-sheet (C_f / G_fa), actuator
    (C_a / G_ab) and, when on, sensor-lag time constants, all as the scenario scales them.
    """
    p = scenario.thermal
    lag = scenario.effects.sensor_lag
    total = p.face_capacitance / p.face_to_actuator + p.actuator_capacitance / p.actuator_to_base
    return SETTLE_TIME_CONSTANTS * (total + (lag.tau_s if lag.enabled else 0.0))


def settled_metrics(
    run: AlignedRun, period_s: float, scenario: Scenario, skip_s: float
) -> RunMetrics | None:
    """Return the run's figures over the periods clear of every base step's transient.

    Whole periods (:func:`es_bringup.metrics.whole_periods`, as the variation counts
    them, from ``skip_s``) that overlap [t_step, t_step + :func:`settle_time`) are left out;
    ``None`` when the scenario has no step (nothing to leave out) or nothing is left.
    """
    steps = step_times(scenario)
    if not steps or run.times.size < 2:
        return None
    dt, samples, start, count = whole_periods(run, period_s, skip_s)
    settle = settle_time(scenario)
    first = run.times[start + samples * np.arange(count)] - dt  # each period's start time
    last = first + samples * dt
    hit = np.zeros(count, dtype=bool)
    for t in steps:
        hit |= (first < t + settle) & (last > t)
    keep = np.flatnonzero(~hit)
    if keep.size == 0:
        return None
    index = (start + samples * keep[:, None] + np.arange(samples)[None, :]).reshape(-1)
    settled = AlignedRun(
        times=run.times[0] + dt * np.arange(index.size),
        setpoint=run.setpoint[index],
        output=run.output[index],
        temperature=run.temperature[index],
        grid_shape=run.grid_shape,
    )
    return run_metrics(settled, period_s)[0]


def estimate_error(run: AlignedRun, scenario: Scenario) -> float:
    """Return the largest |temperature in force - true actuator temperature| of a run, degC.

    The truth comes from the plant core run offline with no voltage (the thermal network
    does not depend on the commands unless ``self_heating`` is on), sampled at the run's
    displacement times as :class:`AlignedRun` pairs them.
    """
    plant = Plant(scenario)
    truth = simulate(plant, commands=np.zeros(plant.shape)[None].repeat(plant.steps, axis=0))
    times = truth.time + plant.dt
    index = np.clip(np.searchsorted(times, run.times - 0.5 * plant.dt), 0, times.size - 1)
    true_temperature = truth.actuator_temperature.reshape(times.size, -1)[index]
    return float(np.max(np.abs(run.temperature - true_temperature)))
