"""Effects compensation: each effect as the plant defines it, undone by the feedforward."""

from __future__ import annotations

import numpy as np
import pytest

from es_feedforward.compensation import (
    CompensationParams,
    CouplingInverse,
    HysteresisInverse,
    RelaxationInverse,
    TemperatureLead,
    drift_factor,
)
from es_feedforward.feedforward import Feedforward, FeedforwardConfig
from es_physics.effects.sensor_lag import SensorLag
from es_physics.laws import hyperbolic_forward

from .plantlike import drift_gain, grid_params, laplacian_of, play

SHAPE = (4, 5)
PARAMS = grid_params(SHAPE, seed=4)
TEMPERATURE = np.linspace(41.0, 51.0, 20).reshape(SHAPE)
NM = 1e-9


def feedforward(**compensation: float) -> Feedforward:
    ff = Feedforward(
        FeedforwardConfig(
            shape=SHAPE, params=PARAMS, compensation=CompensationParams(**compensation)
        )
    )
    ff.update_temperature(TEMPERATURE, 0.0)
    return ff


def smooth_setpoint(phase: float = 0.0) -> np.ndarray:
    rows, cols = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]]
    return (60 + 20 * np.sin(0.7 * rows + 0.4 * cols + phase)) * NM


def test_coupling_is_undone() -> None:
    c = 0.05
    ff = feedforward(coupling=c)
    z_ref = smooth_setpoint()
    voltage = ff.command(z_ref, 0.0).voltage
    z_free = hyperbolic_forward(voltage, TEMPERATURE, PARAMS)
    z_plant = z_free + c * laplacian_of(z_free)
    assert np.max(np.abs(z_plant - z_ref)) < 1e-3 * NM
    # without the compensation the coupling shows
    plain = hyperbolic_forward(feedforward().command(z_ref, 0.0).voltage, TEMPERATURE, PARAMS)
    assert np.max(np.abs(plain + c * laplacian_of(plain) - z_ref)) > 0.1 * NM


def test_coupling_solver_matches_the_laplacian_on_a_large_grid() -> None:
    shape = (64, 64)
    z_ref = np.random.default_rng(0).uniform(0, 1, shape)
    z_free = CouplingInverse(-0.08, shape)(z_ref)
    np.testing.assert_allclose(z_free - 0.08 * laplacian_of(z_free), z_ref, atol=1e-12)


def test_thermal_expansion_is_subtracted() -> None:
    alpha, T_ref = 0.5 * NM, 44.0
    ff = feedforward(thermal_expansion=alpha, expansion_reference_temperature=T_ref)
    z_ref = smooth_setpoint()
    voltage = ff.command(z_ref, 0.0).voltage
    z_plant = hyperbolic_forward(voltage, TEMPERATURE, PARAMS) + alpha * (TEMPERATURE - T_ref)
    assert np.max(np.abs(z_plant - z_ref)) < 1e-3 * NM


def test_drift_is_undone_over_time() -> None:
    a, tau, nu, epoch = 0.1, 50.0, 0.7, 10.0
    ff = feedforward(drift_fraction=a, drift_tau_s=tau, drift_nu=nu, drift_epoch_s=epoch)
    z_ref = smooth_setpoint()
    for t in (10.0, 20.0, 100.0, 1000.0):
        ff.update_temperature(TEMPERATURE, t)
        voltage = ff.command(z_ref, t).voltage
        z_plant = drift_gain(t - epoch, a, tau, nu) * hyperbolic_forward(
            voltage, TEMPERATURE, PARAMS
        )
        assert np.max(np.abs(z_plant - z_ref)) < 1e-3 * NM
    assert drift_factor(CompensationParams(drift_fraction=a), 0.0) == 1.0


def test_hysteresis_is_undone_along_a_trajectory() -> None:
    a, r = 0.3, 20.0
    ff = feedforward(hysteresis_weight=a, hysteresis_threshold_v=r)
    state = np.zeros(SHAPE)
    worst = 0.0
    for step in range(120):  # up, down and up again: the play operator switches branches
        z_ref = smooth_setpoint() * (1 + 0.8 * np.sin(2 * np.pi * step / 60))
        voltage = ff.command(z_ref, step * 0.01).voltage
        state = play(state, voltage, r)
        v_eff = (1 - a) * voltage + a * state
        worst = max(worst, np.max(np.abs(hyperbolic_forward(v_eff, TEMPERATURE, PARAMS) - z_ref)))
    assert worst < 1e-3 * NM


def test_hysteresis_weights_follow_the_temperature_law() -> None:
    # a_i(T) = weight_i exp(-beta (T - T_ref)): the grid spans 41..51 degC around T_ref = 46,
    # so the weights range from 3.5x to 0.29x the reference ones
    weights, thresholds, beta, T_ref = (0.1, 0.05), (8.0, 25.0), 0.25, 46.0
    law = np.exp(-beta * (TEMPERATURE - T_ref))

    def worst_error(decay: float) -> float:
        ff = feedforward(
            hysteresis_weight=weights[0],
            hysteresis_threshold_v=thresholds[0],
            hysteresis_weight_2=weights[1],
            hysteresis_threshold_v_2=thresholds[1],
            hysteresis_decay_per_degc=decay,
            hysteresis_reference_temperature=T_ref,
        )
        states = np.zeros((2, *SHAPE))
        worst = 0.0
        for step in range(120):
            z_ref = smooth_setpoint() * (1 + 0.8 * np.sin(2 * np.pi * step / 60))
            voltage = ff.command(z_ref, step * 0.01).voltage
            v_eff = voltage.copy()
            for k, (w, r) in enumerate(zip(weights, thresholds, strict=True)):
                states[k] = play(states[k], voltage, r)
                v_eff += w * law * (states[k] - voltage)
            z = hyperbolic_forward(v_eff, TEMPERATURE, PARAMS)
            worst = max(worst, float(np.max(np.abs(z - z_ref))))
        return worst

    assert worst_error(beta) < 1e-3 * NM
    # weights taken as they hold at T_ref on every actuator: the cold ones are off by nm
    assert worst_error(0.0) > 0.3 * NM


def test_hysteresis_weights_are_capped_where_the_law_would_sum_them_to_one() -> None:
    inverse = HysteresisInverse((0.3, 0.3), (5.0, 10.0), (3,), 0.5, 46.0)
    a = inverse.weights_at(np.array([40.0, 46.0, 50.0]))
    np.testing.assert_allclose(a.sum(axis=0), [0.9, 0.6, 0.6 * np.exp(-2.0)])
    np.testing.assert_allclose(inverse.weights_at(None), (0.3, 0.3))


def test_hysteresis_inverse_branches() -> None:
    inverse = HysteresisInverse(0.5, 10.0, (3,))
    v_eff = np.array([0.0, 20.0, 4.0])
    voltage = inverse.invert(v_eff)
    # play at 0: 0 stays; 20 pushes the play up (V = V_eff + a r); 4 stays inside (V = 2 V_eff)
    np.testing.assert_allclose(voltage, [0.0, 25.0, 8.0])
    inverse.apply(voltage)
    np.testing.assert_allclose(inverse.play, [[0.0, 15.0, 0.0]])


def test_delay_is_predicted_on_a_ramp() -> None:
    d = 0.004
    ff = feedforward(delay_s=d)
    dt = 0.001
    history: list[np.ndarray] = []
    errors = []
    for step in range(20):
        t = step * dt
        history.append(ff.command(smooth_setpoint() + 100 * NM * t, t).voltage)
        delayed = step - round(d / dt)
        if delayed >= 1:  # the plant applies the command sent d earlier
            z_plant = hyperbolic_forward(history[delayed], TEMPERATURE, PARAMS)
            errors.append(np.max(np.abs(z_plant - (smooth_setpoint() + 100 * NM * t))))
    assert max(errors) < 1e-3 * NM


def test_temperature_lead_undoes_a_first_order_sensor_lag() -> None:
    tau, dt = 5.0, 0.1
    lead = TemperatureLead(tau, filter_s=0.5, noise_degc=0.02)
    actuator = sensor = 40.0
    for step in range(600):  # actuator heats at 0.02 degC/s; the sensor lags by tau
        actuator = 40.0 + 0.02 * step * dt
        sensor += dt / tau * (actuator - sensor)
        used = lead(np.array([sensor]), step * dt)
    assert abs(sensor - actuator) > 0.08  # the lag is real: about tau * rate
    assert used[0] == pytest.approx(actuator, abs=0.005)


def _lagged_noisy_sensor(
    seed: int, noise_degc: float = 0.02
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return times, actuator and sensor temperatures: 2 degC steps, then a ramp.

    The actuator follows its base within 0.04 s, the sensor lags it by 0.1 s and is read
    every 0.02 s with ``noise_degc`` noise and 0.01 degC resolution (the time-scaled thesis
    stand of the calibration loop).
    """
    rng = np.random.default_rng(seed)
    dt, n = 0.02, 1000
    t = np.arange(n) * dt
    base = np.where(t > 15.0, 50.0 + 0.5 * (t - 15.0), 40.0 + 2.0 * np.floor(t / 3.0))
    actuator, sensor = np.empty(n), np.empty(n)
    a = s = 40.0
    for k in range(n):
        for _ in range(10):
            a += dt / 10 / 0.04 * (base[k] - a)
            s += dt / 10 / 0.1 * (a - s)
        actuator[k] = a
        sensor[k] = np.round((s + rng.normal(0.0, noise_degc)) / 0.01) * 0.01
    return t, actuator, sensor


@pytest.mark.parametrize("seed", [0, 1])
def test_temperature_lead_follows_steps_without_amplifying_the_noise(seed: int) -> None:
    # a plain lead T + tau dT/dt (derivative low-passed over tau / 2) errs by 0.10 degC rms
    # here: three times the noise where nothing moves, and slow after each step
    t, actuator, sensor = _lagged_noisy_sensor(seed)
    lead = TemperatureLead(0.1, filter_s=0.05, noise_degc=0.02)
    used = np.array([lead(np.array([T]), tk)[0] for T, tk in zip(sensor, t, strict=True)])
    rms_raw = np.sqrt(np.mean((sensor - actuator)[50:] ** 2))
    rms = np.sqrt(np.mean((used - actuator)[50:] ** 2))
    assert rms_raw > 0.15  # the lag is real
    assert rms < 0.08


@pytest.mark.parametrize("seed", [0, 1])
def test_temperature_lead_with_calibrated_smoothing_averages_the_noise_between_steps(
    seed: int,
) -> None:
    # between the steps (0.5 s on) and along the ramp the lead, set up as a calibration sets
    # it, must average the 0.02 degC noise well below the sensor's own: a jump taken on
    # noise (a 3 sigma gate fires once in ~370 readings) restarts the averaging, which kept
    # the quiet stretches at 0.016-0.032 degC rms (ramp 0.025-0.046) whatever the smoothing
    t, actuator, sensor = _lagged_noisy_sensor(seed)
    values = SensorLag().compensation_values({"tau_s": 0.1}, 0.0)
    lead = TemperatureLead(0.1, values["temperature_lead_filter_s"], noise_degc=0.02)
    used = np.array([lead(np.array([T]), tk)[0] for T, tk in zip(sensor, t, strict=True)])
    quiet = (t > 1.0) & (t < 15.0) & (t % 3.0 >= 0.5)
    ramp = t > 15.5
    assert np.sqrt(np.mean((used - actuator)[quiet] ** 2)) < 0.013
    assert np.sqrt(np.mean((used - actuator)[ramp] ** 2)) < 0.015
    assert np.sqrt(np.mean((used - actuator)[50:] ** 2)) < 0.08  # the steps still followed


def test_temperature_lead_stays_finite_on_a_noise_free_sensor() -> None:
    lead = TemperatureLead(0.1, filter_s=0.05, noise_degc=0.02)
    T = np.full((2, 3), 45.0)
    for step in range(10000):  # the noise estimate shrinks towards its floor
        used = lead(T, step * 0.02)
    assert np.all(used == pytest.approx(45.0))
    for step in range(10000, 10050):  # then a 1 degC step, seen through the lag
        sensor = 46.0 - np.exp(-(step - 10000) * 0.02 / 0.1)
        used = lead(np.full((2, 3), sensor), step * 0.02)
    assert np.all(np.isfinite(used))
    assert np.all(used == pytest.approx(46.0, abs=0.01))


def test_temperature_lead_learns_a_noise_larger_than_assumed() -> None:
    # 0.05 degC noise, 0.02 assumed: with the noise held at 0.02 the jump gate fires on noise
    # (0.24 degC rms); the plain lead errs by 0.15 degC rms
    t, actuator, sensor = _lagged_noisy_sensor(1, noise_degc=0.05)
    lead = TemperatureLead(0.1, filter_s=0.05, noise_degc=0.02)
    used = np.array([lead(np.array([T]), tk)[0] for T, tk in zip(sensor, t, strict=True)])
    assert np.sqrt(np.mean((used - actuator)[50:] ** 2)) < 0.13


def test_unknown_or_out_of_range_compensation_parameters_are_rejected() -> None:
    with pytest.raises(ValueError, match="unknown"):
        CompensationParams.from_mapping({"compensation.bogus": 1.0})
    with pytest.raises(ValueError, match="hysteresis_weight"):
        CompensationParams.from_mapping({"compensation.hysteresis_weight": 0.95})
    ok = CompensationParams.from_mapping({"compensation.delay_s": 0.0024, "coupling": 0.01})
    assert (ok.delay_s, ok.coupling) == (0.0024, 0.01)


def test_three_operator_hysteresis_is_inverted_exactly() -> None:
    weights, thresholds = (0.15, 0.1, 0.2), (5.0, 20.0, 45.0)
    inverse = HysteresisInverse(weights, thresholds, (4,))
    rng = np.random.default_rng(9)
    states = np.zeros((3, 4))  # the forward operator, written out here
    wanted = 150.0 + np.cumsum(rng.normal(0.0, 12.0, (300, 4)), axis=0)
    worst = 0.0
    for v_eff in wanted:
        voltage = inverse.invert(v_eff)
        inverse.apply(voltage)
        for k, r in enumerate(thresholds):
            states[k] = np.clip(states[k], voltage - r, voltage + r)
        played = sum(w * s for w, s in zip(weights, states, strict=True))
        got = (1 - sum(weights)) * voltage + played
        worst = max(worst, float(np.max(np.abs(got - v_eff))))
    assert worst < 1e-9
    np.testing.assert_allclose(inverse.play, states)


def relaxed(voltages: np.ndarray, dt: float, r: float, fc: float) -> np.ndarray:
    """The drive's first-order relaxation written out, seen at the end of each held step.

    V_eff = V - r highpass(V): the low-passed state s relaxes towards the drive held over
    the step, and the output at the step's end is (1 - r) V + r s_end. The state starts at
    the first drive (as the feedforward's inverse assumes).
    """
    decay = np.exp(-2 * np.pi * fc * dt)
    state = voltages[0].copy()
    out = np.empty_like(voltages)
    for i, v in enumerate(voltages):
        state = v + (state - v) * decay
        out[i] = (1 - r) * v + r * state
    return out


def test_relaxation_inverse_undoes_the_forward_filter() -> None:
    r, fc, dt = 0.4, 15.0, 0.01
    inverse = RelaxationInverse(r, fc, (4,))
    rng = np.random.default_rng(3)
    wanted = 150.0 + np.cumsum(rng.normal(0.0, 15.0, (200, 4)), axis=0)
    sent = np.empty_like(wanted)
    for i, v_eff in enumerate(wanted):
        sent[i] = inverse.invert(v_eff, i * dt)
        inverse.apply(sent[i], i * dt)
    assert np.max(np.abs(sent - wanted)) > 5.0  # the inverse does reshape the drive
    # from the third command on the inverse knows the command interval
    np.testing.assert_allclose(relaxed(sent, dt, r, fc)[2:], wanted[2:], rtol=0, atol=1e-9)


def test_relaxation_inverse_keeps_its_state_over_a_hold() -> None:
    r, fc = 0.5, 2.0
    inverse = RelaxationInverse(r, fc, (1,))
    inverse.apply(np.array([0.0]), 0.0)
    inverse.apply(np.array([100.0]), 1.0)
    # held at 100 V for 0.5 s: state 100 (1 - exp(-2 pi fc 0.5)); to get 100 V one interval
    # (1 s, the last one) on, the drive must overshoot by the part still relaxing then
    decayed = 100.0 * (1 - np.exp(-2 * np.pi * fc * 0.5))
    late = r * np.exp(-2 * np.pi * fc * 1.0)
    expected = (100.0 - late * decayed) / (1 - late)
    np.testing.assert_allclose(inverse.invert(np.array([100.0]), 1.5), [expected])


def test_dispersion_is_undone_by_the_feedforward_along_a_trajectory() -> None:
    r, fc, dt = 0.3, 10.0, 0.01
    wanted = np.array(
        [smooth_setpoint() * (1 + 0.6 * np.sin(2 * np.pi * k / 20)) for k in range(150)]
    )
    ff = feedforward(dispersion_fraction=r, dispersion_corner_hz=fc)
    volts = np.array([ff.command(z, k * dt).voltage for k, z in enumerate(wanted)])
    got = hyperbolic_forward(relaxed(volts, dt, r, fc), TEMPERATURE, PARAMS)
    plain = feedforward()
    flat = np.array([plain.command(z, k * dt).voltage for k, z in enumerate(wanted)])
    uncompensated = hyperbolic_forward(relaxed(flat, dt, r, fc), TEMPERATURE, PARAMS)
    assert np.max(np.abs(uncompensated - wanted)) > 1.0 * NM
    # from the third command on (the inverse knows the command interval then)
    assert np.max(np.abs(got - wanted)[2:]) < 1e-3 * NM


def test_dispersion_with_hysteresis_is_undone_in_plant_order() -> None:
    a, thr, r, fc, dt = 0.2, 15.0, 0.3, 10.0, 0.01
    wanted = np.array(
        [smooth_setpoint() * (1 + 0.6 * np.sin(2 * np.pi * k / 30)) for k in range(120)]
    )
    ff = feedforward(
        hysteresis_weight=a,
        hysteresis_threshold_v=thr,
        dispersion_fraction=r,
        dispersion_corner_hz=fc,
    )
    volts = np.array([ff.command(z, k * dt).voltage for k, z in enumerate(wanted)])
    # plant order: play operator first, then the relaxation, then the law
    state = np.zeros(SHAPE)
    played = np.empty_like(volts)
    for k, v in enumerate(volts):
        state = play(state, v, thr)
        played[k] = (1 - a) * v + a * state
    got = hyperbolic_forward(relaxed(played, dt, r, fc), TEMPERATURE, PARAMS)
    assert np.max(np.abs(got - wanted)[2:]) < 1e-3 * NM


def excess_temperature(volts: np.ndarray, dt: float, g: float, tau: float, window: float):
    """Self-heating written out: dT at each command time, heat from the switch before it.

    The switch to V_k heats at g |V_k - V_(k-1)| |(V_k + V_(k-1))/2 - mean| / (2 dt) over the
    following step; dT relaxes towards it with tau; mean is a running mean of the drive.
    """
    out = np.zeros_like(volts)
    excess, power, mean = np.zeros(volts.shape[1:]), np.zeros(volts.shape[1:]), volts[0].copy()
    keep, mean_keep = np.exp(-dt / tau), np.exp(-dt / window)
    for k in range(1, len(volts)):
        excess = g * power + (excess - g * power) * keep
        out[k] = excess
        swing = np.abs(volts[k] - volts[k - 1])
        power = 0.5 * swing * np.abs(0.5 * (volts[k] + volts[k - 1]) - mean) / dt
        mean = volts[k] + (mean - volts[k]) * mean_keep
    return out


def test_self_heating_is_undone_along_a_fast_trajectory() -> None:
    g, tau, window, dt = 2e-5, 0.3, 1.0, 0.01
    wanted = np.array(
        [smooth_setpoint() * (1 + 0.5 * np.sin(2 * np.pi * k / 4)) for k in range(200)]
    )
    ff = feedforward(self_heating_gain=g, self_heating_tau_s=tau, self_heating_mean_window_s=window)
    volts = np.array([ff.command(z, k * dt).voltage for k, z in enumerate(wanted)])
    # the law sees the command at the actuator's temperature, the sensor's plus the excess
    excess = excess_temperature(volts, dt, g, tau, window)
    got = hyperbolic_forward(volts, TEMPERATURE + excess, PARAMS)
    assert excess[-50:].mean() > 0.5  # a warm actuator, so the test has something to undo
    plain = feedforward()
    flat = np.array([plain.command(z, k * dt).voltage for k, z in enumerate(wanted)])
    heated = hyperbolic_forward(
        flat, TEMPERATURE + excess_temperature(flat, dt, g, tau, window), PARAMS
    )
    assert np.max(np.abs(heated - wanted)) > 1.0 * NM
    assert np.max(np.abs(got - wanted)) < 1e-3 * NM
