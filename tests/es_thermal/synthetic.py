"""A small known linear thermal network to test the estimators against (no simulator needed).

The truth is the estimator's own network structure (es_thermal.network) integrated finely,
with its own parameters, a prescribed base-plate profile, sensor lag and seeded noise. The
estimators run on the sensor samples; their error is measured against the true actuator
temperatures at the sample times.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from es_common.arrays import FloatArray
from es_thermal.interpolation import sampling_matrix
from es_thermal.modal import discretise
from es_thermal.network import NetworkParams, continuous_model


@dataclass
class Run:
    """Samples of one synthetic run (K samples)."""

    times: FloatArray  # (K,)
    readings: FloatArray  # (K, S) noisy sensor readings
    heat: FloatArray  # (K, R, C) heat load at the sample times
    truth: FloatArray  # (K, R, C) true actuator temperatures


def dipole_heat(rows: int, cols: int, total_w: float) -> FloatArray:
    """Two Gaussian poles left and right of centre, summing to ``total_w``."""
    r, c = np.meshgrid(np.linspace(-1, 1, rows), np.linspace(-1, 1, cols), indexing="ij")
    poles = np.exp(-((c - 0.6) ** 2 + r**2) / 0.1) + np.exp(-((c + 0.6) ** 2 + r**2) / 0.1)
    shape = 0.9 * poles / poles.sum() + 0.1 / (rows * cols)
    return np.asarray(total_w * shape, float)


def simulate(
    rows: int,
    cols: int,
    positions: FloatArray,
    params: NetworkParams,
    *,
    duration: float,
    sample_period: float,
    heat: Callable[[float], FloatArray],
    base: Callable[[float], float],
    sensor_tau: float | FloatArray = 0.0,
    noise: float = 0.01,
    substeps: int = 5,
    seed: int = 0,
) -> Run:
    """Integrate the network finely; the heat load is held per sample interval.

    ``heat(t)`` is the load from sample time t on (what /dm/heat_load carries); ``base(t)``
    the base-plate temperature; ``sensor_tau`` one lag for all sensors or one per sensor.
    """
    sampling = sampling_matrix(rows, cols, positions)
    A, B, _, layout = continuous_model(params, rows, cols, sampling, 0.0)
    dt = sample_period / substeps
    # Base plate as an input: take it out of the state and drive it.
    b_col = A[:, layout.base].copy()
    keep = np.arange(layout.size - 1)
    A_d, B_d = discretise(A[np.ix_(keep, keep)], np.column_stack([B[keep], b_col[keep]]), dt)
    tau = np.asarray(sensor_tau, float)
    decay = np.where(tau > 0, np.exp(-dt / np.where(tau > 0, tau, 1.0)), 0.0)
    rng = np.random.default_rng(seed)
    t0 = base(0.0)
    x = np.full(keep.size, t0)
    lagged = np.full(positions.shape[0], t0)
    steps = round(duration / sample_period)
    out = Run(
        times=np.zeros(steps),
        readings=np.zeros((steps, positions.shape[0])),
        heat=np.zeros((steps, rows, cols)),
        truth=np.zeros((steps, rows, cols)),
    )
    act = layout.actuator
    for k in range(steps):
        # The heat load is held over each sample interval, as the estimator assumes it.
        power = heat(k * sample_period).ravel()
        for j in range(substeps):
            u = np.concatenate([power, [base(k * sample_period + (j + 0.5) * dt)]])
            x = A_d @ x + B_d @ u
            site = sampling @ x[act]
            lagged = site + (lagged - site) * decay
        t = (k + 1) * sample_period
        out.times[k] = t
        out.readings[k] = lagged + noise * rng.standard_normal(lagged.size)
        out.heat[k] = heat(t)
        out.truth[k] = x[act].reshape(rows, cols)
    return out
