"""Plant-side definitions of the effects (docs/architecture.md), written independently of the
feedforward's compensation so that tests check one against the other."""

from __future__ import annotations

import numpy as np

from es_physics.params import ActuatorParams, FloatArray


def laplacian_of(z: FloatArray) -> FloatArray:
    """4-neighbour discrete Laplacian, edges: only existing neighbours."""
    out = np.zeros_like(z)
    out[1:, :] += z[:-1, :] - z[1:, :]
    out[:-1, :] += z[1:, :] - z[:-1, :]
    out[:, 1:] += z[:, :-1] - z[:, 1:]
    out[:, :-1] += z[:, 1:] - z[:, :-1]
    return out


def play(previous: FloatArray, V: FloatArray, r: float) -> FloatArray:
    """Backlash operator of half-width r."""
    return np.maximum(V - r, np.minimum(V + r, previous))


def drift_gain(t: float, fraction: float, tau: float, nu: float) -> float:
    return 1.0 - fraction * (1.0 - np.exp(-((t / tau) ** nu)))


def grid_params(shape: tuple[int, int], seed: int = 1) -> ActuatorParams:
    """Per-actuator maps inside the thesis's 95 % intervals."""
    rng = np.random.default_rng(seed)
    return ActuatorParams(
        m1=rng.uniform(-45e-18, -38e-18, shape),
        m2=rng.uniform(1300e-18, 1700e-18, shape),
        k1=rng.uniform(-19e-9, -16e-9, shape),
        k2=rng.uniform(1100e-9, 1250e-9, shape),
        Tm=rng.uniform(37.0, 39.0, shape),
    )
