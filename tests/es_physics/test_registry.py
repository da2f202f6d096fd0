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

import pytest

from es_feedforward.calibration.model import CANDIDATES
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
    from es_feedforward.calibration.align import MeasuredData
    from es_feedforward.calibration.pipeline import calibrate
    from es_physics.effects import candidates
    from es_sim_plant.effects import EFFECT_NAMES

    assert "linear_creep" in candidates(), candidates()
    assert "linear_creep" not in EFFECT_NAMES  # no simulator model: the plant refuses it
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


def test_external_effect_is_found_and_calibrated(tmp_path: Path) -> None:
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
    env = {**os.environ, "PYTHONPATH": path}
    proc = subprocess.run(
        [sys.executable, "-c", CALIBRATE_WITH_EXAMPLE],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    found = json.loads(proc.stdout.strip().splitlines()[-1])
    assert list(found) == ["linear_creep"], found
    assert found["linear_creep"]["rate_m_per_s"] == pytest.approx(5e-11, rel=0.05)
