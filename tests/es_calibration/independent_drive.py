"""Test-stand recordings (testing/standgen) with independently driven actuators, or two clocks.

The stand's program switches every actuator's segment at the same instants (one signal
generator, per-actuator phases and scales). A characterisation of a real mirror drives its
actuators independently: here each actuator gets its own program, drawn by standgen's own
``make_program`` for a 1 x 1 grid, so its segment boundaries (the edges its 250 Hz command
cannot resolve) fall at its own instants. Everything else is standgen's ``simulate``.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from unittest import mock

import numpy as np
import numpy.typing as npt
import standgen.stand
from standgen import Recording, StandConfig, simulate
from standgen._typing import FloatArray
from standgen.program import VoltageProgram, make_program


class IndependentProgram:
    """One standgen program per actuator, evaluated together as the stand's program."""

    def __init__(self, programs: list[VoltageProgram], shape: tuple[int, int]) -> None:
        """Hold ``programs`` (row-major, one per actuator of ``shape``)."""
        self.programs = programs
        self.shape = shape

    def __call__(self, t: npt.ArrayLike) -> FloatArray:
        """Return the voltage (N, R, C) [V] at times ``t`` (N,) [s]."""
        columns = [p(t)[:, 0, 0] for p in self.programs]  # a test-sized grid
        return np.stack(columns, axis=1).reshape(-1, *self.shape)


def _independent(rng: np.random.Generator, duration_s: float, shape: tuple[int, int],
                 rate_hz: float) -> IndependentProgram:
    count = shape[0] * shape[1]
    programs = [make_program(rng, duration_s, (1, 1), rate_hz) for _ in range(count)]
    return IndependentProgram(programs, shape)


@contextmanager
def independent_drive() -> Iterator[None]:
    """Within the context, standgen's ``simulate`` drives each actuator independently."""
    with mock.patch.object(standgen.stand, "make_program", _independent):
        yield


def simulate_independent(config: StandConfig) -> Recording:
    """Return standgen's recording of ``config`` with independently driven actuators."""
    with independent_drive():
        return simulate(config)


def with_clock_rate(recording: Recording, ppm: float) -> Recording:
    """Return ``recording`` with the displacement logged on a clock ``ppm`` fast.

    The displacement of the true instant t is stamped t0 + (t - t0)(1 + ppm 1e-6), t0 the
    first displacement's instant (where the two clocks were set equal).
    """
    t = recording.displacement_times
    stamped = t[0] + (t - t[0]) * (1.0 + ppm * 1e-6)
    return replace(recording, displacement_times=stamped)
