"""The noise floor from the residual's second differences, on a quantised read-out.

The test stand's interferometer reads in 0.1 nm steps: the second differences of its noise
sit on a lattice, whose median absolute deviation moves by whole steps (+-6 to 10 % of the
noise at 0.2-0.5 nm); the trimmed rms does not.
"""

from __future__ import annotations

import numpy as np
import pytest

from es_calibration.search.residual import noise_floor

STEP_M = 0.1e-9


@pytest.mark.parametrize("noise_m", [0.2e-9, 0.4e-9, 0.5e-9, 1e-9])
def test_noise_floor_of_a_quantised_read_out_is_its_noise(noise_m: float) -> None:
    rng = np.random.default_rng(1)
    read = np.round(noise_m * rng.standard_normal((4, 30000)) / STEP_M) * STEP_M
    true = np.hypot(noise_m, STEP_M / np.sqrt(12.0))  # white noise and quantisation
    contiguous = np.ones(read.shape[1] - 1, bool)
    assert noise_floor(read, contiguous) == pytest.approx(true, rel=0.015)
    # outliers (a sample every 500 rows 20x the noise off) stay out of it
    spiked = read.copy()
    spiked[:, ::500] += 20.0 * noise_m
    assert noise_floor(spiked, contiguous) == pytest.approx(true, rel=0.015)
    # a smooth model error cancels; broken runs are not differenced across
    t = np.arange(read.shape[1]) / 5000.0
    drifting = read + 3e-9 * np.sin(2 * np.pi * 2.0 * t)
    contiguous[::97] = False
    assert noise_floor(drifting, contiguous) == pytest.approx(true, rel=0.015)
