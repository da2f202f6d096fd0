"""Factor 19, the slew-rate limiter: its recursion, its compiled twin, and the feedforward.

A step ramps at the limit and then holds; a command within the limit passes unchanged; the
calibration's compiled loop gives the same numbers; a term of the limit is written for the
model but never undone (within the limit there is nothing to undo, beyond it no command is
faster), so the feedforward's discovered stage leaves the command alone.
"""

from __future__ import annotations

import numpy as np
import pytest

from es_physics.effects.discovered import (
    BY_CODE,
    Carrier,
    Discovered,
    Term,
    rate_limited,
    values_from_terms,
)

PERIOD = 1e-3


def test_a_step_ramps_at_the_limit_then_holds() -> None:
    command = np.zeros((12, 2))
    command[2:, 0] = 10.0
    command[2:, 1] = -3.0
    out = rate_limited(command, PERIOD, 2000.0)  # 2 V per sample
    assert out[:, 0].tolist() == [0, 0, 2, 4, 6, 8, 10, 10, 10, 10, 10, 10]
    assert out[:, 1].tolist() == [0, 0, -2, -3, -3, -3, -3, -3, -3, -3, -3, -3]


def test_a_command_within_the_limit_passes_unchanged() -> None:
    t = np.arange(500) * PERIOD
    command = (50.0 * np.sin(2 * np.pi * 5.0 * t))[:, None]  # at most 1571 V/s
    np.testing.assert_allclose(rate_limited(command, PERIOD, 2000.0), command, rtol=0, atol=1e-12)


def test_the_compiled_twin_gives_the_same_numbers() -> None:
    pytest.importorskip("numba")
    from es_calibration.model.rate_limit_loop import rate_limit_rows

    command = np.random.default_rng(1).normal(0.0, 5.0, (400, 3)).cumsum(axis=0)
    command[17, 1] = np.nan  # NaN propagates as in np.clip
    out = np.empty_like(command)
    rate_limit_rows(command, 3.0, out)
    np.testing.assert_array_equal(out, rate_limited(command, 1.0, 3.0))


def test_a_limit_term_is_written_but_never_undone() -> None:
    term = Term(1.0, (19, 4000.0), None, Carrier.DRIVE)
    assert not term.compensable
    assert BY_CODE[19].side == "drive"
    values = values_from_terms([term])
    assert values["discovered_1_factor_a"] == 19.0
    assert Discovered().compensator(values, (2, 2)) is None
