"""The effect registry: one definition per effect, read by plant, calibration and feedforward."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from dataclasses import fields
from pathlib import Path
from typing import Any

import pytest

from es_calibration.model.composite import CANDIDATES
from es_feedforward.compensation import RANGES, CompensationParams
from es_physics.effects import (
    EffectError,
    Parameter,
    Role,
    UnknownEffectError,
    candidates,
    get,
    names,
    registry,
)
from es_sim_plant.effects import EFFECT_NAMES, Effects

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "tests" / "fixtures" / "es_effect_example"
BUILT_IN = (
    "sensor_lag",
    "delay",
    "hysteresis",
    "coupling",
    "thermal_expansion",
    "drift",
    "temperature_curvature",
    "self_heating",
    "frequency_dispersion",
)


def test_built_in_effects_are_registered_under_their_canonical_names() -> None:
    assert names()[: len(BUILT_IN)] == BUILT_IN
    assert set(BUILT_IN) <= set(EFFECT_NAMES)
    # every built-in effect has a calibration model now
    assert set(BUILT_IN) <= set(candidates())
    assert candidates() == CANDIDATES
    with pytest.raises(UnknownEffectError, match="magic"):
        get("magic")


def test_compensation_parameters_are_the_effects_declarations() -> None:
    declared = {p.name: p for e in registry().values() for p in e.compensation}
    defaults = CompensationParams()
    assert {f.name for f in fields(CompensationParams)} == set(declared)
    for name, p in declared.items():
        assert getattr(defaults, name) == p.default, name
        assert RANGES[name] == (p.low, p.high)


def test_plant_settings_follow_the_declared_parameters() -> None:
    effects = Effects()
    for name in EFFECT_NAMES:
        settings = getattr(effects, name)
        assert not settings.enabled
        assert [k for k, _ in settings.values] == [p.name for p in get(name).plant]
    lag = Effects.from_dict({"sensor_lag": {"enabled": True, "tau_s": 2.0}}).time_scaled(3.0)
    assert lag.sensor_lag.tau_s == 6.0  # a declared slow time
    with pytest.raises(EffectError, match=r"effects\.coupling\.coefficient"):
        Effects.from_dict({"coupling": {"enabled": True, "coefficient": 0.125}})
    with pytest.raises(EffectError, match="tau_s"):
        Effects.from_dict({"drift": {"tau_s": float("nan")}})


def test_parameter_ranges_are_checked_with_open_and_closed_ends() -> None:
    p = Parameter("x", "s", 0.0, 1.0, 0.5, "x", low_open=True)
    assert p.accepts(1.0) and not p.accepts(0.0) and not p.accepts(float("nan"))
    assert p.range_text() == "(0, 1]"


def test_every_single_effect_role_is_taken_once() -> None:
    roles = [e.role for e in registry().values() if e.role not in (Role.ADDITIVE, Role.PLANT_ONLY)]
    assert len(roles) == len(set(roles))


# --- an effect from another package, through the entry-point group ------------------------

CALIBRATE_WITH_EXAMPLE = textwrap.dedent(
    """
    import json
    import numpy as np
    from es_calibration.data.align import MeasuredData
    from es_calibration.pipeline import calibrate
    from es_physics.effects import candidates
    from es_sim_plant.effects import EFFECT_NAMES

    assert "linear_creep" in candidates(), candidates()
    assert "linear_creep" in EFFECT_NAMES  # its plant stage: the simulator has it too
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 120.0, 0.01)
    V = 150.0 + 120.0 * np.sin(2 * np.pi * 1.0 * t)
    T = 44.0 + 2.0 * np.sin(2 * np.pi * t / 120.0)
    Ts = T - 38.0  # the thesis law written out here, independent of es_physics
    M = 1504e-18 - 41.5e-18 * Ts
    k = 1167.5e-9 - 17.375e-9 * Ts
    L = 0.2e-3
    z = M * L / k**2 * np.tanh(k * V / L) ** 2 + 5e-11 * t
    z = z + 0.5e-9 * rng.standard_normal(t.size)
    grid = lambda x: x[:, None, None]
    measured = MeasuredData(t, grid(V), t + 0.001, grid(z), t[::10], grid(T[::10]))
    cal = calibrate(measured, ("drift", "thermal_expansion", "linear_creep"))
    print(json.dumps({e.name: e.parameters for e in cal.effects}))
    """
)


LOOP_WITH_EXAMPLE = textwrap.dedent(
    """
    import json
    import sys
    from dataclasses import replace
    from pathlib import Path

    import numpy as np
    import yaml
    from es_calibration.data.align import MeasuredData
    from es_calibration.pipeline import calibrate
    from es_calibration.output.schema import write_parameters_yaml
    from es_feedforward.feedforward import Feedforward, Mode
    from es_feedforward.param_file import read_params_file
    from es_sim_plant.plant import Plant, simulate
    from es_sim_plant.scenario import load_scenario, resolve_scenario

    # m/s: -1.3 nm over the test stand, -0.6 nm over the closed loop (a creep down: the
    # set point troughs at 0 nm stay reachable, electrostriction only expands)
    RATE = -3e-11
    work = Path(sys.argv[1])
    creep = {"linear_creep": {"enabled": True, "rate_m_per_s": RATE}}

    def scenario(name, effects, label, **overrides):
        data = yaml.safe_load(resolve_scenario(name).read_text())
        # the test stand measures the loop's own mirror (as the main job's does)
        loop = yaml.safe_load(resolve_scenario("thesis_ac").read_text())
        for key in ("grid", "seed", "thermal", "sensors", "actuators"):
            data.pop(key, None)
            if key in loop:
                data[key] = loop[key]
        data["effects"] = effects
        path = work / f"{name}_{label}.yaml"
        path.write_text(yaml.safe_dump(data))
        return load_scenario(str(path)).with_overrides(**overrides)

    # 1. the plant simulates the external effect on a test stand (no controller)
    stand = scenario("characterisation", creep, "creep")
    run = simulate(Plant(stand))
    dt = 1.0 / stand.control_rate
    measured = MeasuredData(
        run.time, run.command, run.time + dt, run.displacement_measured,
        run.sensor_time, run.temperature_raw.reshape(-1, 1, 1),
    )
    # 2. the calibration finds it among every candidate and writes the feedforward's file
    cal = calibrate(measured)
    params = work / "feedforward.yaml"
    write_parameters_yaml(cal, params)
    config = replace(read_params_file(params), mode=Mode.INVERSE_HYPERBOLIC)

    # 3. the feedforward compensates it in a closed loop with the plant
    def closed_loop(config, effects, label):
        sc = scenario("thesis_ac", effects, label, control_rate=50.0)
        core = Feedforward(config)

        def controller(obs):
            if obs.temperature_raw is not None:
                core.update_temperature(obs.temperature_raw.reshape(sc.shape), obs.time)
            return core.command(obs.setpoint, obs.time).voltage

        result = simulate(Plant(sc), controller=controller)
        skip = round(sc.control_rate / sc.setpoint.sine_frequency)
        error = (result.displacement - result.setpoint)[skip:]
        return float(np.sqrt(np.mean(error**2)))

    off = replace(config, compensation=config.compensation.replaced({"creep_rate_m_per_s": 0.0}))
    print(json.dumps({
        "found": {e.name: e.parameters for e in cal.effects},
        "compensation": {k: v for k, v in config.compensation.values().items() if "creep" in k},
        "rms_compensated": closed_loop(config, creep, "creep"),
        "rms_uncompensated": closed_loop(off, creep, "creep"),
        "rms_without_effect": closed_loop(off, {}, "none"),
    }))
    """
)


@pytest.fixture(scope="module")
def example_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Install the example effect package into a site folder; return an env that sees it."""
    tmp_path = tmp_path_factory.mktemp("example")
    site = tmp_path / "site"
    source = tmp_path / "es_effect_example"  # setuptools builds in the source tree: a copy
    shutil.copytree(EXAMPLE, source)
    pip = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation"]
    subprocess.run(
        [*pip, "--target", str(site), str(source)],
        check=True,
        capture_output=True,
        timeout=300,
        cwd=tmp_path,
    )
    path = os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])
    return {**os.environ, "PYTHONPATH": path}


def _run(script: str, env: dict[str, str], *args: str) -> dict[str, Any]:
    proc = subprocess.run(
        [sys.executable, "-c", script, *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def test_external_effect_is_found_and_calibrated(example_env: dict[str, str]) -> None:
    found = _run(CALIBRATE_WITH_EXAMPLE, example_env)
    assert list(found) == ["linear_creep"], found
    assert found["linear_creep"]["rate_m_per_s"] == pytest.approx(5e-11, rel=0.05)


def test_external_effect_is_simulated_calibrated_and_compensated(
    example_env: dict[str, str], tmp_path: Path
) -> None:
    """Plant -> calibrate -> feedforward with an effect only the example package defines."""
    out = _run(LOOP_WITH_EXAMPLE, example_env, str(tmp_path))
    assert list(out["found"]) == ["linear_creep"], out
    assert out["found"]["linear_creep"]["rate_m_per_s"] == pytest.approx(-3e-11, rel=0.1)
    assert out["compensation"]["creep_rate_m_per_s"] == pytest.approx(-3e-11, rel=0.1)
    # the creep costs the loop without its compensation, and nothing with it
    assert out["rms_uncompensated"] > 3.0 * out["rms_without_effect"], out
    assert out["rms_compensated"] <= 1.5 * out["rms_without_effect"], out
