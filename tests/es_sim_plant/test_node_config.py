"""es_sim_plant.node_config: the plant node's parameters -> scenario and lockstep settings."""

from __future__ import annotations

import pytest

from es_node_runtime.errors import ParameterTypeError
from es_node_runtime.param_spec import ParameterValues
from es_sim_plant.effects import EFFECT_NAMES
from es_sim_plant.node_config import (
    SPECS,
    LockstepSettings,
    base_scenario,
    configured_scenario,
    effect_specs,
    resonance_spec,
    settings_from_parameters,
)
from es_sim_plant.scenario import load_scenario


def values(**changes: object) -> ParameterValues:
    """Return the defaults of every plant parameter with ``changes``."""
    out: dict[str, object] = {spec.name: spec.default for spec in SPECS}
    out.update(changes)
    return ParameterValues(out)


def switches(**changes: object) -> ParameterValues:
    """Return dm_exposure's switches (effects, resonance) at their defaults with ``changes``."""
    scenario = load_scenario("dm_exposure")
    specs = [*effect_specs(scenario), resonance_spec(scenario)]
    out: dict[str, object] = {spec.name: spec.default for spec in specs}
    out.update(changes)
    return ParameterValues(out)


def test_the_defaults_keep_the_scenario_as_it_is() -> None:
    scenario = base_scenario(values())
    assert configured_scenario(scenario, values(), switches()) == load_scenario("dm_exposure")


def test_overrides_replace_the_scenarios_values_and_unset_ones_keep_them() -> None:
    given = values(rows=3, cols=5, control_rate=200.0, seed=7, displacement_noise=1e-9)
    scenario = configured_scenario(base_scenario(given), given, switches())
    shipped = load_scenario("dm_exposure")
    assert (scenario.rows, scenario.cols, scenario.control_rate) == (3, 5, 200.0)
    assert scenario.seed == 7 and scenario.displacement_noise == 1e-9
    assert scenario.sensor_rate == shipped.sensor_rate and scenario.duration == shipped.duration


def test_time_scale_reloads_the_scenario_scaled() -> None:
    scaled = base_scenario(values(time_scale=2.0))
    assert scaled == load_scenario("dm_exposure", 2.0)
    assert scaled.duration != load_scenario("dm_exposure").duration


def test_switches_turn_effects_and_the_resonance_sweeps_on_and_off() -> None:
    name = next(n for n in EFFECT_NAMES if n != "sensor_lag")
    on = switches(**{f"effects.{name}": True, "resonance": True})
    scenario = configured_scenario(base_scenario(values()), values(), on)
    assert name in scenario.effects.enabled_names() and scenario.resonance.enabled
    off = switches(**{"effects.sensor_lag": False})
    assert "sensor_lag" not in configured_scenario(
        base_scenario(values()), values(), off
    ).effects.enabled_names()


def test_an_out_of_range_override_raises_a_readable_value_error() -> None:
    given = values(sensor_rate=1000.0)  # above the 100 Hz control rate
    with pytest.raises(ValueError, match="sensor_rate must not exceed control_rate"):
        configured_scenario(base_scenario(given), given, switches())


def test_settings_come_from_the_parameters() -> None:
    assert settings_from_parameters(values()) == LockstepSettings()
    given = values(
        lockstep=False, command_timeout=0.25, wait_ready=["thermal"], start_subscribers=1,
        max_speed=3.0, exit_when_done=True,
    )  # fmt: skip
    settings = settings_from_parameters(given)
    assert not settings.lockstep and settings.command_timeout == 0.25
    assert settings.wait_ready == ("thermal",) and settings.start_subscribers == 1
    assert settings.max_speed == 3.0 and settings.exit_when_done


def test_a_value_of_the_wrong_type_names_the_parameter() -> None:
    with pytest.raises(ParameterTypeError, match="command_timeout"):
        settings_from_parameters(values(command_timeout="soon"))


def test_the_checks_reject_unknown_scenarios_and_bad_node_lists() -> None:
    by_name = {spec.name: spec for spec in SPECS}
    assert by_name["scenario"].reason_to_reject("no_such_scenario") is not None
    assert by_name["scenario"].reason_to_reject("thesis_ac") is None
    assert by_name["wait_ready"].reason_to_reject(["thermal", ""]) is not None
    assert by_name["wait_ready"].reason_to_reject(["thermal"]) is None
