"""Estimators against the simulator's true actuator temperatures (es_sim_plant core).

Uses the benchmark's accuracy run (bench/bench_thermal.py) on shortened scenarios; the
figures are printed (``pytest -s``) and the assertions hold with margin: the model estimator
must beat the thesis-style low-pass, by 3x on the heating scenario.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_thermal.py"


def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_thermal", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses need the module registered
    spec.loader.exec_module(module)
    return module


bench = _bench()


def _show(name: str, figures: dict[str, float]) -> None:
    print(
        f"\n{name}: model rms {figures['thermal_rms_model']:.4f} max "
        f"{figures['thermal_max_model']:.4f} lag {figures['thermal_lag_model']:.2f} s | "
        f"lowpass rms {figures['thermal_rms_lowpass']:.4f} max "
        f"{figures['thermal_max_lowpass']:.4f} lag {figures['thermal_lag_lowpass']:.2f} s"
    )


def test_model_beats_lowpass_on_heating_scenario() -> None:
    # Thermal parameters 20 % off in mixed directions: gains and time constants both wrong.
    figures = bench.thermal_accuracy("dm_exposure", duration=12.0, pattern="mixed")
    _show("dm_exposure 2x2 sensors, parameters 20 % off (mixed)", figures)
    assert figures["temperature_span"] > 2.0  # the mirror really heats
    assert figures["thermal_rms_model"] < figures["thermal_rms_lowpass"] / 3
    assert figures["thermal_rms_model"] < 0.03


def test_sensor_lag_is_compensated_with_dense_sensors() -> None:
    figures = bench.thermal_accuracy(
        "dm_exposure", pitch=1, noise=0.02, duration=6.0, effects={"sensor_lag": True}
    )
    _show("dm_exposure, sensor per actuator, sensor lag", figures)
    assert figures["thermal_rms_model"] < figures["thermal_rms_lowpass"] / 3
    assert figures["thermal_lag_model"] < figures["thermal_lag_lowpass"]


@pytest.mark.parametrize("scenario", ["thesis_ac", "thesis_dc_ac"])
def test_thesis_base_plate_scenarios(scenario: str) -> None:
    # No heat load: the base plate (Peltier stage) moves and the model must estimate it.
    figures = bench.thermal_accuracy(
        scenario, pitch=1, noise=0.02, sensor_rate=100.0, effects={"sensor_lag": True}
    )
    _show(f"{scenario}, sensor lag", figures)
    assert figures["temperature_span"] > 9.0
    assert figures["thermal_rms_model"] < figures["thermal_rms_lowpass"]
