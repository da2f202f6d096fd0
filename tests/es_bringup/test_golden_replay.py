"""Deterministic regression tier: replay each golden bag's inputs through every node's core.

The golden bags (tests/golden, made by ``scripts/regen-golden`` from the real node graph)
hold every message of a short lockstep run. Each core gets the inputs its node received, in
the order of the lockstep protocol, and must reproduce the outputs its node published:

- message counts exactly: K steps -> K + 1 displacements (the last one after the final
  step), K set points and K commands, one raw, heat-load and estimate per sensor step;
- plant core (``es_sim_plant.plant``) fed the recorded /dm/command: set points, heat loads,
  raw temperatures and displacements;
- thermal core (``es_thermal.estimator``) fed the recorded heat loads and raw temperatures:
  the recorded /dm/temperature;
- feedforward core (``es_feedforward.feedforward``) fed the recorded set points and
  estimates: the recorded /dm/command.

Tolerances: the same code on the same inputs gives the same numbers, so the comparison is to
floating-point noise, ``np.allclose(rtol=1e-9, atol=ATOL)`` with ATOL = 1e-15 m, 1e-9 degC,
1e-9 V (a few ulp of the values; NumPy builds may differ in the last bits of transcendental
functions). Times are the protocol's t_k = k / control_rate (the nodes use sim time for
staleness only; no golden case depends on it).

Order: a sensor step's heat load comes before its readings at the thermal node, and its
estimate before its set point at the feedforward node (the plant sends them in that order
and both nodes serve those subscriptions first), so set point k uses the estimate of the
newest sensor step <= k. A node that breaks this order fails here.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from es_bringup.bringup import scenario_parameters
from es_bringup.golden import CASES, GoldenCase
from es_feedforward.feedforward import Feedforward
from es_feedforward.node_params import parameter_specs
from es_feedforward.param_file import config_from_parameters as feedforward_config
from es_msgs_py import topics
from es_msgs_py.bag import TopicSeries, read_bag
from es_sim_plant.plant import Plant, simulate
from es_sim_plant.scenario import Scenario
from es_thermal.estimator import TemperatureEstimator
from es_thermal.node_params import SPECS as THERMAL_SPECS
from es_thermal.node_params import config_from_parameters as thermal_config

GOLDEN = Path(__file__).resolve().parents[1] / "golden"
RTOL = 1e-9
ATOL_M, ATOL_DEGC, ATOL_V = 1e-15, 1e-9, 1e-9


def values_of(bag: dict[str, TopicSeries], topic: str) -> np.ndarray:
    values = bag[topic].values
    assert values is not None, f"{topic} holds no arrays"
    return values


@pytest.fixture(scope="module", params=CASES, ids=[c.name for c in CASES])
def golden(request: pytest.FixtureRequest) -> tuple[GoldenCase, Scenario, dict[str, TopicSeries]]:
    case: GoldenCase = request.param
    return case, case.load(), read_bag(GOLDEN / case.name)


def test_message_counts_are_exact(golden: tuple[GoldenCase, Scenario, dict]) -> None:
    _, scenario, bag = golden
    steps = round(scenario.duration * scenario.control_rate)
    every = round(scenario.control_rate / scenario.sensor_rate)
    samples = math.ceil(steps / every)
    expected = {
        topics.DISPLACEMENT: steps + 1,
        topics.SETPOINT: steps,
        topics.COMMAND: steps,
        topics.HEAT_LOAD: samples,
        topics.TEMPERATURE_RAW: samples,
        topics.TEMPERATURE: samples,
    }
    assert {t: len(bag[t]) for t in expected} == expected
    assert len(bag[topics.DIAGNOSTICS]) > 0


def test_plant_core_reproduces_the_plant_outputs(golden: tuple[GoldenCase, Scenario, dict]) -> None:
    _, scenario, bag = golden
    commands = values_of(bag, topics.COMMAND)
    result = simulate(Plant(scenario), commands=commands)
    np.testing.assert_allclose(
        values_of(bag, topics.SETPOINT), result.setpoint, rtol=RTOL, atol=ATOL_M
    )
    displacement = values_of(bag, topics.DISPLACEMENT)
    np.testing.assert_allclose(displacement[0], 0.0, atol=ATOL_M)  # before the first step
    np.testing.assert_allclose(displacement[1:], result.displacement, rtol=RTOL, atol=ATOL_M)
    np.testing.assert_allclose(
        values_of(bag, topics.TEMPERATURE_RAW), result.temperature_raw, rtol=RTOL, atol=ATOL_DEGC
    )
    np.testing.assert_allclose(
        values_of(bag, topics.HEAT_LOAD),
        result.heat_load[result.sensor_step],
        rtol=RTOL,
        atol=1e-15,
    )


def test_thermal_core_reproduces_the_estimates(golden: tuple[GoldenCase, Scenario, dict]) -> None:
    case, scenario, bag = golden
    values: dict[str, object] = {spec.name: spec.default for spec in THERMAL_SPECS}
    values.update(scenario_parameters(case.scenario, case.plant)[0])
    core = TemperatureEstimator(thermal_config(values))
    every = round(scenario.control_rate / scenario.sensor_rate)
    heat, raw = values_of(bag, topics.HEAT_LOAD), values_of(bag, topics.TEMPERATURE_RAW)
    replayed = []
    for j in range(len(raw)):
        core.set_heat_load(heat[j])
        estimate = core.update(j * every / scenario.control_rate, raw[j])
        assert estimate.temperatures is not None
        replayed.append(estimate.temperatures)
    np.testing.assert_allclose(
        values_of(bag, topics.TEMPERATURE), np.array(replayed), rtol=RTOL, atol=ATOL_DEGC
    )


def test_feedforward_core_reproduces_the_commands(
    golden: tuple[GoldenCase, Scenario, dict],
) -> None:
    case, scenario, bag = golden
    values: dict[str, object] = {spec.name: spec.default for spec in parameter_specs()}
    values.update(scenario_parameters(case.scenario, case.plant)[1])
    values["mode"] = case.mode
    core = Feedforward(feedforward_config(values))
    every = round(scenario.control_rate / scenario.sensor_rate)
    setpoints, commands = values_of(bag, topics.SETPOINT), values_of(bag, topics.COMMAND)
    estimates = values_of(bag, topics.TEMPERATURE)
    replayed = []
    for k, setpoint in enumerate(setpoints):
        if k % every == 0:
            sample = k // every
            core.update_temperature(estimates[sample], sample * every / scenario.control_rate)
        replayed.append(core.command(setpoint, k / scenario.control_rate).voltage)
    np.testing.assert_allclose(commands, np.array(replayed), rtol=RTOL, atol=ATOL_V)
