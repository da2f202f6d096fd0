"""The feedforward undoes a discovered output-side term (closed on the model).

The plant here is the basic law plus the term's truth, computed in the test with its own
exact zero-order-hold low-pass: the command with the term compensated must hold the set point
better than the same feedforward without it, and stay finite and within v_limit.
"""

from __future__ import annotations

import numpy as np

from es_feedforward.compensation import CompensationParams
from es_feedforward.feedforward import Feedforward, FeedforwardConfig
from es_physics.effects.discovered import Term, values_from_terms
from es_physics.laws import hyperbolic_forward
from es_physics.params import ActuatorParams

SHAPE = (3, 4)
PERIOD = 2e-3
TAU = 0.4
COEFFICIENT = 2e-13  # m/V^2: a few nm at the drive used


def _run(compensation: CompensationParams) -> tuple[float, np.ndarray]:
    """Return the RMS error to the set point [m] and all commands, over 3 s of a sine."""
    config = FeedforwardConfig(shape=SHAPE, compensation=compensation)
    ff = Feedforward(config)
    params = ActuatorParams()
    T = np.full(SHAPE, config.reference_temperature)
    decay = np.exp(-PERIOD / TAU)
    lowpass = np.zeros(SHAPE)  # LP(V^2), V held over each period
    phases = np.linspace(0.0, 1.0, SHAPE[0] * SHAPE[1]).reshape(SHAPE)
    errors, commands = [], []
    for k in range(1500):
        t = k * PERIOD
        ff.update_temperature(T, t)
        z_set = 90e-9 + 60e-9 * np.sin(2 * np.pi * (1.5 * t + phases))
        v = np.asarray(ff.command(z_set, t).voltage)
        z = hyperbolic_forward(v, T, params) + COEFFICIENT * lowpass
        lowpass = v**2 + (lowpass - v**2) * decay  # the plant's state over the held command
        if t > 1.0:
            errors.append(z - z_set)
        commands.append(v)
    return float(np.sqrt(np.mean(np.square(errors)))), np.asarray(commands)


def test_output_side_discovered_term_is_compensated() -> None:
    term = Term(COEFFICIENT, (11, TAU))
    with_term = CompensationParams().replaced(values_from_terms([term]))
    rms_with, commands = _run(with_term)
    rms_without, _ = _run(CompensationParams())
    assert rms_without > 2e-9  # the term matters at this drive
    assert rms_with < 0.05 * rms_without
    assert np.all(np.isfinite(commands))
    assert commands.max() <= FeedforwardConfig(shape=SHAPE).v_limit


def test_drive_side_terms_are_not_compensated_and_zero_is_off() -> None:
    from es_physics.effects import get

    effect = get("discovered")
    assert effect.compensator(CompensationParams().of("discovered"), SHAPE) is None
    drive_only = values_from_terms([Term(1e-12, (1, 0.0), (2, 0.0))])  # V * dV/dt
    assert effect.compensator({**CompensationParams().of("discovered"), **drive_only},
                              SHAPE) is None
