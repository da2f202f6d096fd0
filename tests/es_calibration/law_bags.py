"""Small measured-data bags from the hyperbolic law alone (numpy, no simulator).

Every actuator follows z = (M L / k^2) tanh^2(k V / L) with M, k linear in T* and a small
spread between actuators, plus white interferometer noise. The base temperature makes one
turn (40 -> 50 -> 40 degC, a half sine over the record), so that a straight line across a
gap at the turn misses the temperature by most of a degree. Commands and displacements at
``RATE``; the displacement of command k is stamped half a period after it. Topics are
(times, values) pairs; gaps and drops are cut out of them before writing.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from es_msgs_py.bag import write_array_bag
from es_physics.laws import hyperbolic_forward
from es_physics.params import ActuatorParams

RATE = 250.0
TEMPERATURE_RATE = 10.0
NOISE_M = 0.2e-9
GRID = (2, 2)
#: Height of a command step [V] (``law_run``'s ``steps``).
STEP_V = 40.0

Series = dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]


@dataclass
class LawRun:
    """One synthetic run: the truth at the command times and the topics to write."""

    t: npt.NDArray[np.float64]  # command times [s]
    voltage: npt.NDArray[np.float64]  # (N, R, C) [V]
    temperature: npt.NDArray[np.float64]  # (N, R, C) [degC] at the displacement times
    clean: npt.NDArray[np.float64]  # (N, R, C) noise-free displacement [m]
    topics: Series


def temperature_profile(t: npt.NDArray[np.float64], duration: float) -> npt.NDArray[np.float64]:
    """Return the base temperature [degC]: one turn, 40 -> 50 -> 40 degC over ``duration``."""
    return 40.0 + 10.0 * np.sin(np.pi * t / duration)


def law_run(
    duration: float = 90.0,
    seed: int = 1,
    shape: tuple[int, int] = GRID,
    steps: tuple[float, ...] = (),
) -> LawRun:
    """Return a run of ``duration`` s on a ``shape`` grid of actuators.

    ``steps``: times [s] at which the command steps up by ``STEP_V`` (and stays there).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / RATE)
    phase = rng.uniform(0.0, 2.0 * np.pi, (2, *shape))
    tt = t[:, None, None]
    voltage = (
        160.0
        + 90.0 * np.sin(2 * np.pi * 1.1 * tt + phase[0])
        + 50.0 * np.sin(2 * np.pi * 2.7 * tt + phase[1])
        + STEP_V * sum((tt >= when).astype(np.float64) for when in steps)
    )
    t_disp = t + 0.5 / RATE
    offsets = rng.uniform(-0.3, 0.3, shape)
    temperature = temperature_profile(t_disp, duration)[:, None, None] + offsets
    base = ActuatorParams().as_arrays(shape)
    params = replace(
        base,
        m2=base.m2 * (1.0 + 0.02 * rng.standard_normal(shape)),
        k2=base.k2 * (1.0 + 0.01 * rng.standard_normal(shape)),
    )
    clean = hyperbolic_forward(voltage, temperature, params)
    t_temp = np.arange(0.0, duration, 1.0 / TEMPERATURE_RATE)
    temp_msgs = temperature_profile(t_temp, duration)[:, None, None] + offsets
    temp_msgs = temp_msgs + 0.005 * rng.standard_normal(temp_msgs.shape)
    return LawRun(
        t=t,
        voltage=voltage,
        temperature=temperature,
        clean=clean,
        topics={
            "/dm/command": (t, voltage),
            "/dm/displacement": (t_disp, clean + NOISE_M * rng.standard_normal(clean.shape)),
            "/dm/temperature": (t_temp, temp_msgs),
        },
    )


def cut(series: Series, topic: str, start: float, end: float) -> Series:
    """Return ``series`` without the messages of ``topic`` stamped in [start, end)."""
    t, v = series[topic]
    keep = (t < start) | (t >= end)
    return {**series, topic: (t[keep], v[keep])}


def drop_random(series: Series, topic: str, fraction: float, seed: int = 5) -> Series:
    """Return ``series`` with a random ``fraction`` of the messages of ``topic`` dropped."""
    t, v = series[topic]
    keep = np.random.default_rng(seed).random(t.size) >= fraction
    return {**series, topic: (t[keep], v[keep])}


def write(series: Series, path: Path) -> Path:
    """Write ``series`` as an MCAP bag at ``path``."""
    write_array_bag(path, series)
    return path
