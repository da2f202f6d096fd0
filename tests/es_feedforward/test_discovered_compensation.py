"""The feedforward undoes discovered terms (closed on the model).

The plant here is the basic law plus the term's truth, computed in the test with its own
code (an exact zero-order-hold low-pass; an amplifier that droops with the commands' rate; an
interior that runs behind the sensed temperature): the command with the term compensated
must hold the set point better than the same feedforward without it, and stay finite and
within v_limit.
"""

from __future__ import annotations

import numpy as np

from es_feedforward.compensation import CompensationParams
from es_feedforward.feedforward import Feedforward, FeedforwardConfig
from es_physics.effects.discovered import (
    SOLVE_TOLERANCE_V,
    Carrier,
    DiscoveredCompensation,
    Term,
    terms_from_values,
    values_from_terms,
)
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


def _neighbour_mean(x: np.ndarray) -> np.ndarray:
    """The test's own 4-neighbour mean (edges: the neighbours that exist)."""
    padded = np.pad(x, 1, constant_values=np.nan)
    stack = np.stack([padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]])
    return np.asarray(np.nanmean(stack, axis=0))


def _rim_depth(shape: tuple[int, int]) -> np.ndarray:
    r = np.arange(shape[0])[:, None]
    c = np.arange(shape[1])[None, :]
    d = np.minimum(np.minimum(r, shape[0] - 1 - r), np.minimum(c, shape[1] - 1 - c))
    return d / d.max()


DROOP = -1.2e-5  # V/(V V/s): the amplifier loses 1.2 % of V per 1 kV/s
RATE_LIMIT = 4000.0  # V/s: the droop stops growing beyond this rate
LAG_S = 1.0  # s: the interior's temperature lags its neighbours' rate


def _run_plant(compensation: CompensationParams, *, droop: bool, lag: bool,
               shape: tuple[int, int] = (4, 4)) -> tuple[float, np.ndarray, Feedforward]:
    """RMS error [m] over 2 s of a fast sine on a warming grid: the plant's amplifier droops
    (the test's own backward difference of the commands) and / or the interior runs behind
    the sensed temperature (the test's own neighbour mean of the sensed rate)."""
    config = FeedforwardConfig(shape=shape, compensation=compensation)
    ff = Feedforward(config)
    params = ActuatorParams()
    depth = _rim_depth(shape)
    phases = np.linspace(0.0, 1.0, shape[0] * shape[1]).reshape(shape)
    previous = None
    errors, commands = [], []
    for k in range(1000):
        t = k * PERIOD
        T = 45.0 + 0.5 * t + 0.3 * phases * t  # every actuator warms at its own rate
        ff.update_temperature(T, t)
        z_set = 90e-9 + 50e-9 * np.sin(2 * np.pi * (12.0 * t + phases))
        v = np.asarray(ff.command(z_set, t).voltage)
        v_eff = v
        if droop and previous is not None:
            rate = np.minimum(np.abs(v - previous) / PERIOD, RATE_LIMIT)
            v_eff = v + DROOP * v * rate
        T_true = T - LAG_S * depth * _neighbour_mean(0.5 + 0.3 * phases) if lag else T
        z = hyperbolic_forward(v_eff, T_true, params)
        previous = v
        if t > 0.2:
            errors.append(z - z_set)
        commands.append(v)
    return float(np.sqrt(np.mean(np.square(errors)))), np.asarray(commands), ff


def test_a_drive_term_is_solved_from_the_voltage_the_law_asks_for() -> None:
    term = Term(DROOP, (1, 0.0), (15, RATE_LIMIT), Carrier.DRIVE)
    with_term = CompensationParams().replaced(values_from_terms([term]))
    rms_with, commands, ff = _run_plant(with_term, droop=True, lag=False)
    rms_without, _, _ = _run_plant(CompensationParams(), droop=True, lag=False)
    assert rms_without > 1e-9  # the droop matters at this drive
    # the terms' rate is taken on the law's voltages, the plant's on the commands (they
    # differ by the compensation's own steps): measured 0.15 x
    assert rms_with < 0.25 * rms_without
    assert np.all(np.isfinite(commands))
    assert commands.min() >= 0.0 and commands.max() <= FeedforwardConfig(shape=(4, 4)).v_limit
    assert ff.compensation_counters() == {"discovered.drive_out_of_reach": 0}


def test_a_temperature_term_moves_the_temperature_the_law_is_inverted_at() -> None:
    term = Term(-LAG_S, (9, 0.0), (16, 0.0), Carrier.TEMPERATURE)
    with_term = CompensationParams().replaced(values_from_terms([term]))
    rms_with, commands, _ = _run_plant(with_term, droop=False, lag=True)
    rms_without, _, _ = _run_plant(CompensationParams(), droop=False, lag=True)
    assert rms_without > 1e-10
    assert rms_with < 0.05 * rms_without
    assert np.all(np.isfinite(commands))


def test_a_drive_term_that_does_not_settle_sends_the_first_step_and_counts_it() -> None:
    shape = (2, 2)
    # the voltage in effect is minus the command: the fixed-point steps run away
    stage = DiscoveredCompensation([Term(-2.0, (1, 0.0), None, Carrier.DRIVE)], shape)
    target = np.full(shape, 50.0)
    out = stage.invert_drive(target, 0.0)
    np.testing.assert_allclose(out, 3.0 * target)  # target - (-2 target): the first step
    assert stage.unconverged == 4
    assert stage.counters() == {"drive_out_of_reach": 4}


def test_a_drive_term_that_settles_is_solved_within_the_tolerance() -> None:
    shape = (2, 3)
    # the voltage in effect is 0.95 of the command: each step shrinks the miss 20-fold, so
    # the steps settle (within 1e-6 V of a 6 V first miss) in 6 of FIXED_POINT_STEPS
    gain = -0.05
    stage = DiscoveredCompensation([Term(gain, (1, 0.0), None, Carrier.DRIVE)], shape)
    target = np.linspace(10.0, 120.0, 6).reshape(shape)
    out = stage.invert_drive(target, 0.0)
    np.testing.assert_allclose(out + gain * out, target, rtol=0.0, atol=SOLVE_TOLERANCE_V)
    assert stage.unconverged == 0


def test_a_term_of_non_finite_value_counts_as_zero() -> None:
    shape = (2, 2)
    # 1 nm per degC above 45 degC: an inf or NaN temperature makes the term non-finite,
    # and the set point passes unchanged there
    stage = DiscoveredCompensation([Term(1e-9, (3, 45.0))], shape)
    z = np.full(shape, 80e-9)
    T = np.array([[50.0, np.inf], [np.nan, 46.0]])
    out = stage.setpoint(z, T, 0.0)
    np.testing.assert_allclose(out, z - 1e-9 * np.array([[5.0, 0.0], [0.0, 1.0]]))


def test_terms_keep_where_they_act_through_the_parameters_file() -> None:
    terms = [Term(-0.7, (9, 0.0), (16, 0.0), Carrier.TEMPERATURE),
             Term(-1e-5, (1, 0.0), (15, 4e3), Carrier.DRIVE), Term(2e-13, (11, 0.4))]
    assert terms_from_values(values_from_terms(terms)) == terms
    assert all(t.compensable for t in terms)
    # of the modelled displacement, a drive or temperature term cannot be solved
    assert not Term(1.0, (6, 0.0), None, Carrier.DRIVE).compensable
    assert not Term(1.0, (6, 0.0), None, Carrier.TEMPERATURE).compensable
    # the present command in a temperature or displacement term: not from the set point
    assert not Term(1.0, (15, 0.0), None, Carrier.TEMPERATURE).compensable
    assert not Term(1.0, (1, 0.0), (15, 0.0)).compensable


def _creep_plant(x: np.ndarray, x_old: np.ndarray, lags: np.ndarray, h: float,
                 shortest: float) -> np.ndarray:
    """Advance the plant's creep lags over a step ``h`` (x held linearly from ``x_old``)."""
    taus = shortest * 10.0 ** np.arange(lags.shape[0])
    d = np.exp(-h / taus).reshape(-1, 1, 1)
    c = ((1.0 - np.exp(-h / taus)) * taus / h).reshape(-1, 1, 1)
    return d * lags + (1.0 - c) * x + (c - d) * x_old


def test_a_creep_term_is_undone_exactly_from_the_displacement_the_law_gives() -> None:
    gamma, shortest = 0.02, 0.01
    stage = DiscoveredCompensation([Term(gamma, (20, shortest))], SHAPE)
    rng = np.random.default_rng(3)
    lags: np.ndarray | None = None
    x_old = np.zeros(SHAPE)
    for k in range(400):
        t = k * PERIOD
        z_set = np.full(SHAPE, 80e-9) + (20e-9 if (k // 50) % 2 else 0.0) + 1e-9 * rng.random(
            SHAPE)
        x = stage.setpoint(z_set, np.zeros(SHAPE), t)  # what the law must give
        if lags is None:
            lags = np.broadcast_to(x, (4, *SHAPE)).copy()
        else:
            lags = _creep_plant(x, x_old, lags, PERIOD, shortest)
        measured = x + gamma * np.sum(lags - x, axis=0)
        np.testing.assert_allclose(measured, z_set, rtol=0, atol=1e-18)
        stage.commit(np.zeros(SHAPE), np.zeros(SHAPE), t)
        x_old = x


def test_a_creep_term_is_compensable_only_alone_on_the_displacement() -> None:
    assert Term(0.02, (20, 0.01)).compensable
    assert not Term(0.02, (20, 0.01), (3, 45.0)).compensable
    assert not Term(0.02, (20, 0.01), None, Carrier.DRIVE).compensable


def test_a_creep_the_command_cannot_undo_passes_the_set_point_as_it_is() -> None:
    # gamma x the decades' weights >= 1: no displacement solves it; the set point goes on
    stage = DiscoveredCompensation([Term(0.3, (20, 0.01))], SHAPE)
    z = np.full(SHAPE, 80e-9)
    stage.setpoint(z, np.zeros(SHAPE), 0.0)
    stage.commit(np.zeros(SHAPE), np.zeros(SHAPE), 0.0)
    np.testing.assert_array_equal(stage.setpoint(z + 20e-9, np.zeros(SHAPE), PERIOD), z + 20e-9)


def test_a_creep_term_keeps_bad_set_points_from_the_actuators() -> None:
    term = Term(0.02, (20, 0.01))
    config = FeedforwardConfig(shape=SHAPE, compensation=CompensationParams().replaced(
        values_from_terms([term])))
    ff = Feedforward(config)
    T = np.full(SHAPE, config.reference_temperature)
    for k, value in enumerate((80e-9, np.nan, np.inf, -5e-9, 80e-9)):
        ff.update_temperature(T, k * PERIOD)
        z = np.full(SHAPE, 80e-9)
        z[0, 0] = value
        v = np.asarray(ff.command(z, k * PERIOD).voltage)
        assert np.all(np.isfinite(v)) and np.all((v >= 0.0) & (v <= config.v_limit))
