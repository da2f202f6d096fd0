"""Effect stages: the plant and the feedforward chain them from the registry, naming none."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from es_feedforward.compensation import CompensationParams
from es_feedforward.feedforward import Feedforward, FeedforwardConfig
from es_physics.effects import (
    Effect,
    EffectError,
    FittedEffect,
    PlantContext,
    Role,
    in_model_order,
    names,
    registry,
)
from es_physics.effects.registry import _checked
from es_sim_plant.effects import EFFECT_NAMES, Effects
from es_sim_plant.plant import Plant
from es_sim_plant.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
CHAINS = (
    ROOT / "src/es_sim_plant/es_sim_plant/actuators.py",
    ROOT / "src/es_sim_plant/es_sim_plant/plant.py",
    ROOT / "src/es_feedforward/es_feedforward/feedforward.py",
)


def test_model_order_is_role_order_then_registry_order() -> None:
    order = in_model_order()
    roles = list(Role)
    keys = [(roles.index(e.role), names().index(e.name)) for e in order]
    assert keys == sorted(keys)
    assert [e.name for e in in_model_order(["coupling", "hysteresis"])] == [
        "hysteresis",
        "coupling",
    ]


def test_plant_and_feedforward_chains_name_no_effect() -> None:
    for path in CHAINS:
        text = path.read_text()
        for name in names():
            # as a string or an attribute (``effects.<name>``): a branch on the effect
            pattern = rf"[\"']{name}[\"']|\.{name}\b"
            assert not re.search(pattern, text), f"{path.name} names {name}"


def test_every_simulated_effect_builds_a_plant_stage() -> None:
    sc = load_scenario("thesis_ac").with_overrides(
        rows=2, cols=2, effects=dict.fromkeys(EFFECT_NAMES, True)
    )
    plant = Plant(sc)
    assert len(plant.actuators.stages) == len(EFFECT_NAMES)
    assert plant.actuators.sensor_lag_s == sc.effects.sensor_lag.tau_s
    assert plant.actuators.heating_power is None  # before the first step
    z = plant.step(np.full(sc.shape, 150.0))
    assert np.all(np.isfinite(z)) and plant.actuators.heating_power is not None
    assert Effects().stages(PlantContext((2, 2), 0.01, 10, 40.0)) == []  # all off


def test_a_compensator_is_built_only_for_parameters_that_are_on() -> None:
    off = Feedforward(FeedforwardConfig(shape=(2, 2)))
    assert not off._stages
    on = Feedforward(
        FeedforwardConfig(
            shape=(2, 2),
            compensation=CompensationParams(delay_s=0.01, hysteresis_weight=0.1, coupling=0.02),
        )
    )
    assert list(on._stages) == [e.name for e in in_model_order(["delay", "hysteresis", "coupling"])]


def test_a_simulated_effect_without_plant_stage_is_refused() -> None:
    class Broken(Effect):
        name = "broken"
        summary = "claims a simulator model it does not have"
        role = Role.ADDITIVE
        simulated = True

        def reported(self, fit: FittedEffect) -> dict[str, float]:
            return {}

    with pytest.raises(EffectError, match="plant_stage"):
        _checked(Broken())
    assert "broken" not in registry()
