"""Measured-data bags recorded from the plant core (es_sim_plant) for the calibration tests.

A short characterisation run: the test stand drives every actuator with a voltage program
while the base temperature ramps, and the interferometer adds noise. Stamps follow the
lock-step node: the command of step k at t_k, the displacement it produces at t_k+1.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from es_msgs_py.bag import write_array_bag
from es_sim_plant.plant import Plant, SimulationResult, simulate
from es_sim_plant.scenario import Scenario

NOISE_M = 0.2e-9
TIME_SCALE = 0.02


def scenario(
    rows: int = 1,
    cols: int = 1,
    duration: float = 24.0,
    rate: float = 250.0,
    effects: dict[str, Any] | None = None,
    noise: float = NOISE_M,
    seed: int = 3,
) -> Scenario:
    """Return a characterisation scenario: 40 -> 52 -> 42 degC, offsets, amplitudes, 1-4 Hz.

    ``duration`` is simulation time; thermal times (and the slow effect times given in
    ``effects``) are physical and shortened by ``TIME_SCALE``.
    """
    physical = duration / TIME_SCALE
    return Scenario.from_dict(
        {
            "name": "calibration_test",
            "grid": {"rows": rows, "cols": cols},
            "control_rate": rate,
            "sensor_rate": 10.0,
            "duration": physical,
            "time_scale": TIME_SCALE,
            "seed": seed,
            "base_temperature": {
                "points": [[0, 40.0], [physical / 2, 52.0], [physical, 42.0]],
            },
            "sensors": {"noise_sd": 0.01, "resolution": 0.0, "offset_sd": 0.0},
            "actuators": {"spread": {"m2": 0.02, "k2": 0.01}},
            "excitation": {
                "offsets_v": [0.0, 100.0],
                "amplitudes_v": [50.0, 150.0, 250.0],
                "frequencies_hz": [1.0, 4.0],
                "level_s": 1.0,
                "phase_spread": True,
            },
            "effects": effects or {},
            "displacement_noise": noise,
        }
    )


def run(scn: Scenario) -> SimulationResult:
    """Simulate ``scn`` with its own excitation."""
    return simulate(Plant(scn))


def write_bag(result: SimulationResult, path: Path, storage: str = "mcap") -> Path:
    """Write the measured-data topics of ``result`` as a bag at ``path``."""
    dt = 1.0 / result.scenario.control_rate
    write_array_bag(
        path,
        {
            "/dm/command": (result.time, result.command),
            "/dm/displacement": (result.time + dt, result.displacement_measured),
            "/dm/temperature/raw": (result.sensor_time, result.temperature_raw),
        },
        storage=storage,
    )
    return path


def truth_rms(result: SimulationResult) -> float:
    """Return the rms of the interferometer noise actually drawn."""
    noise = result.displacement_measured - result.displacement
    return float(np.sqrt(np.mean(noise * noise)))
