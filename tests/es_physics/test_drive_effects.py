"""The drive-dependent effects' shared pieces: relaxation filter and heating estimate."""

from __future__ import annotations

import numpy as np
import pytest

from es_physics.effects.frequency_dispersion import (
    relaxation_advance,
    relaxation_decay,
    relaxation_inverse,
    relaxation_output,
)
from es_physics.effects.self_heating import HeatingEstimate


def test_relaxation_passes_dc_and_cuts_fast_drive_by_the_fraction() -> None:
    r, decay = 0.25, relaxation_decay(5.0, 0.001)
    state = np.zeros(1)
    for _ in range(5000):  # 5 s of 100 V: the state settles, the output is the drive
        out = relaxation_output(np.array([100.0]), state, r)
        state = relaxation_advance(np.array([100.0]), state, decay)
    assert out[0] == pytest.approx(100.0, rel=1e-9)
    # a sudden step of 10 V: at first only 1 - r of it acts
    step = relaxation_output(np.array([110.0]), state, r)
    assert step[0] - 100.0 == pytest.approx(10.0 * (1 - r))
    np.testing.assert_allclose(relaxation_inverse(step, state, r), [110.0])


@pytest.mark.parametrize("fraction", [1.0, -0.1, float("nan")])
def test_relaxation_inverse_needs_a_fraction_below_one(fraction: float) -> None:
    with pytest.raises(ValueError, match="fraction"):
        relaxation_inverse(np.zeros(2), np.zeros(2), fraction)


def test_relaxation_decay_rejects_bad_corners_and_steps() -> None:
    with pytest.raises(ValueError, match="corner"):
        relaxation_decay(0.0, 0.01)
    with pytest.raises(ValueError, match="step"):
        relaxation_decay(1.0, float("nan"))


def test_heating_estimate_rises_under_fast_drive_and_decays_on_hold() -> None:
    est = HeatingEstimate(1e-4, 0.5, 1.0)
    assert est.at(0.0) == 0.0
    for k in range(100):  # 50 Hz square wave 100 +- 20 V, 1 s
        est.apply(np.array([120.0 if k % 2 else 80.0]), k * 0.01)
    warm = float(np.asarray(est.at(0.99))[0])
    assert warm > 0.1
    assert float(np.asarray(est.at(0.99 + 2.0))[0]) < 0.1 * warm  # held: no swing, no heat
    with pytest.raises(ValueError, match="tau"):
        HeatingEstimate(1e-4, 0.0, 1.0)
    with pytest.raises(ValueError, match="gain"):
        est.retuned(float("nan"), 1.0, 1.0)
