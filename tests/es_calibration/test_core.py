"""Unit tests of the calibration cores: model, batched fit, alignment, residual statistics."""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
import pytest

from es_calibration.data.align import (
    SPAN_DROPS,
    CalibrationInputError,
    MeasuredData,
    align,
)
from es_calibration.model.composite import (
    CANDIDATES,
    CompositeModel,
    FitInputs,
    neighbour_laplacian,
    play_operator,
)
from es_calibration.model.fit import levenberg_marquardt
from es_calibration.model.history import DriveHistory, DriveSamples, first_order_lowpass
from es_calibration.search.residual import integrated_autocorrelation_time, noise_floor
from es_feedforward.kernels import KERNELS_ENV
from es_physics.effects import EffectError
from es_physics.effects import get as get_effect
from es_physics.effects.coupling import grid_laplacian
from es_physics.effects.hysteresis import play
from es_physics.laws import hyperbolic_forward
from es_physics.params import ActuatorParams


def _inputs(rng: np.random.Generator, A: int = 6, n: int = 400, grid=(2, 3)) -> FitInputs:
    t = np.linspace(0.0, 20.0, n)
    V = 150.0 + 120.0 * np.sin(2 * np.pi * 0.7 * t + rng.uniform(0, 6, (A, 1)))
    T = 44.0 + 4.0 * np.sin(2 * np.pi * t / 40.0) + rng.uniform(-0.5, 0.5, (A, 1))
    return FitInputs(
        t=t,
        voltage=V,
        play=(V + rng.uniform(-5, 5, V.shape))[None],
        temperature=T,
        temperature_rate=np.gradient(T, t, axis=1),
        displacement=np.zeros_like(V),
        valid=np.ones(V.shape, bool),
        grid=grid,
        mean_temperature=44.0,
        drive=DriveSamples(DriveHistory(V.T, t[1] - t[0]), ((np.arange(n), 1.0),)),
    )


def test_play_operator_matches_the_plant_definition() -> None:
    rng = np.random.default_rng(0)
    command = np.cumsum(rng.normal(0, 5, (500, 3)), axis=0)
    keep = np.array([0, 7, 7, 100, 499])
    got = play_operator(command, 12.0, keep)
    state = np.clip(np.zeros(3), command[0] - 12.0, command[0] + 12.0)
    expected = []
    for i, row in enumerate(command):
        state = play(state, row, 12.0)
        expected.extend([state] * int(np.sum(keep == i)))
    np.testing.assert_allclose(got, np.asarray(expected))


@pytest.mark.parametrize(
    ("command_shape", "threshold", "state"),
    [
        ((700, 3), 12.0, None),  # one threshold for every actuator
        ((700, 3), np.array([0.0, 5.0, 40.0]), np.array([3.0, -2.0, 1e3])),  # per actuator
        ((700, 1), np.array([[2.0], [9.0], [30.0]]), None),  # a stack of thresholds, 1 column
        ((700, 2), np.array([[2.0], [9.0]]), np.zeros((2, 2))),  # thresholds x actuators
    ],
)
def test_the_compiled_play_operator_gives_numpys_numbers(
    monkeypatch: pytest.MonkeyPatch, command_shape, threshold, state
) -> None:
    # the effect search runs the compiled loop (play_loop.py); numpy's must agree exactly,
    # NaN commands (a hole) and repeated or skipped rows included
    rng = np.random.default_rng(3)
    command = np.cumsum(rng.normal(0, 5, command_shape), axis=0)
    command[200:203, 0] = np.nan
    keep = np.array([0, 7, 7, 150, 201, 300, 301, 699, 699])
    results = {}
    for backend in ("numpy", "fused"):
        monkeypatch.setenv(KERNELS_ENV, backend)
        results[backend] = play_operator(command, threshold, keep, state)
    assert "es_calibration.model.play_loop" in sys.modules  # the compiled loop ran
    assert results["fused"].shape == results["numpy"].shape
    np.testing.assert_array_equal(results["fused"], results["numpy"])
    assert np.isnan(results["numpy"][4]).any() and np.isfinite(results["numpy"][2]).all()


def test_laplacian_matches_the_plant_definition() -> None:
    values = np.random.default_rng(1).normal(size=(3, 4, 5))
    got = neighbour_laplacian(values.reshape(12, 5), (3, 4))
    np.testing.assert_allclose(
        got, grid_laplacian(values.transpose(2, 0, 1)).transpose(1, 2, 0).reshape(12, 5)
    )


def test_model_without_effects_is_the_hyperbolic_law() -> None:
    rng = np.random.default_rng(2)
    data = _inputs(rng)
    p = ActuatorParams()
    local = np.tile([p.m2, p.m1, p.k2, p.k1], (6, 1))
    got = CompositeModel(()).evaluate(local, np.zeros(0), data).prediction
    np.testing.assert_allclose(got, hyperbolic_forward(data.voltage, data.temperature, p))


@pytest.mark.parametrize("per_actuator", [False, True])
@pytest.mark.parametrize("coupled", [False, True])
def test_jacobians_match_finite_differences(coupled: bool, per_actuator: bool) -> None:
    rng = np.random.default_rng(3)
    data = _inputs(rng)
    effects = [e for e in CANDIDATES if e != "delay" and (coupled or e != "coupling")]
    local_keys = ("sensor_lag.tau_s", "self_heating.gain") if per_actuator else ()
    model = CompositeModel(effects, per_actuator=local_keys)
    p = ActuatorParams()
    law = [float(v) for v in (p.m2, p.m1, p.k2, p.k1)]
    law += [1e-19, 1e-10, *[3.0, 1e-4][: len(local_keys)]]
    local = np.tile(law, (6, 1)) * rng.uniform(0.95, 1.05, (6, len(law)))
    assert model.local_names[6:] == local_keys
    values = {
        "sensor_lag.tau_s": 3.0,
        "hysteresis.weight": 0.05,
        "hysteresis.decay_per_degc": 0.2,
        "coupling.coefficient": 0.04,
        "thermal_expansion.alpha_m_per_degc": 4e-10,
        "thermal_expansion.offset_m": 1e-9,
        "drift.fraction": 0.03,
        "drift.log_tau_s": np.log(6.0),
        "drift.log_nu": -0.5,
        "self_heating.gain": 1e-4,
        "self_heating.log_tau_s": np.log(1.5),
        "self_heating.log_mean_window_s": np.log(1.3),
        "frequency_dispersion.fraction": 0.08,
        "frequency_dispersion.log_corner_hz": np.log(0.5),
    }
    glob = np.array([values[n] for n in model.global_names])
    ev = model.evaluate(local, glob, data)
    for j in range(glob.size):
        h = 1e-6 * max(abs(glob[j]), 1e-9)
        up, down = glob.copy(), glob.copy()
        up[j] += h
        down[j] -= h
        fd = (
            model.evaluate(local, up, data).prediction
            - model.evaluate(local, down, data).prediction
        ) / (2 * h)
        np.testing.assert_allclose(
            ev.jac_global[..., j],
            fd,
            rtol=1e-4,
            atol=1e-6 * np.abs(fd).max(),
            err_msg=model.global_names[j],
        )
    for j in range(local.shape[1]):
        h = 1e-6 * np.abs(local[:, j]).max()
        up, down = local.copy(), local.copy()
        up[:, j] += h
        down[:, j] -= h
        fd = (
            model.evaluate(up, glob, data).prediction - model.evaluate(down, glob, data).prediction
        ) / (2 * h)
        if coupled:  # only the actuator's own term: neighbours' terms are O(c) and dropped
            assert np.abs(ev.jac_local[..., j] - fd).max() <= 0.3 * np.abs(fd).max()
        else:
            np.testing.assert_allclose(
                ev.jac_local[..., j], fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max()
            )


def test_batched_fit_recovers_many_actuators_with_honest_uncertainties() -> None:
    rng = np.random.default_rng(4)
    A = 200
    data = _inputs(rng, A=A, n=600, grid=(10, 20))
    true = ActuatorParams(
        m2=1504e-18 * rng.uniform(0.9, 1.1, (A, 1)), k2=1167.5e-9 * rng.uniform(0.95, 1.05, (A, 1))
    )
    noise = 0.3e-9
    z = hyperbolic_forward(data.voltage, data.temperature, true)
    z = z + noise * rng.standard_normal(z.shape)
    model = CompositeModel(())
    p = ActuatorParams()
    start = np.tile([p.m2, p.m1, p.k2, p.k1], (A, 1))
    result = levenberg_marquardt(
        lambda loc, glo, jac: model.evaluate(loc, glo, data, jac), z, data.valid, start, np.zeros(0)
    )
    sigma = np.sqrt(result.cov_local[:, 0, 0])
    pull = (result.local[:, 0] - np.asarray(true.m2)[:, 0]) / sigma
    assert np.abs(pull).max() < 5.0
    assert 0.7 < np.std(pull) < 1.3  # the uncertainties are neither too small nor too large
    np.testing.assert_allclose(np.sqrt(result.cost / result.count), noise, rtol=0.15)


def test_shared_parameter_is_fitted_jointly_with_the_laws() -> None:
    rng = np.random.default_rng(5)
    data = _inputs(rng, A=6, n=800)
    model = CompositeModel(("thermal_expansion",))
    p = ActuatorParams()
    local = np.tile([p.m2, p.m1, p.k2, p.k1], (6, 1))
    truth = np.array([0.4e-9, 2e-9])
    z = model.evaluate(local * 1.03, truth, data).prediction + 0.1e-9 * rng.standard_normal(
        data.voltage.shape
    )
    result = levenberg_marquardt(
        lambda loc, glo, jac: model.evaluate(loc, glo, data, jac), z, data.valid, local, np.zeros(2)
    )
    err = np.abs(result.glob - truth) / np.sqrt(np.diag(result.cov_global))
    assert np.all(err < 5.0)
    np.testing.assert_allclose(result.glob[0], 0.4e-9, rtol=0.05)


def _measured(n: int = 3000, rate: float = 100.0) -> MeasuredData:
    t = np.arange(n) / rate
    V = (100 + 50 * np.sin(t))[:, None, None] * np.ones((1, 2, 2))
    T_times = 0.35 + np.arange(int(n / rate * 4)) / 4.0  # slower and starting later
    T = (44 + 0.1 * T_times)[:, None, None] * np.ones((1, 2, 2))
    z = hyperbolic_forward(V, 44.0, ActuatorParams())
    return MeasuredData(t, V, t + 0.5 / rate, z, T_times, T)


def test_alignment_handles_rates_start_times_and_nan() -> None:
    data = _measured()
    data.displacement[100, 0, 1] = np.nan
    data.temperature[5, 1, 1] = np.nan
    aligned = align(data)
    assert aligned.dropped["displacement NaN"] == 1
    assert aligned.dropped["temperature NaN"] == 1
    # the samples before the first temperature message (0.35 s) are left out, not held
    t_disp = data.displacement_times
    assert aligned.dropped[SPAN_DROPS] == int((t_disp < 0.35).sum()) == 35
    assert aligned.t[0] + aligned.start_time >= 0.35
    np.testing.assert_array_equal(aligned.sample_index, np.flatnonzero(t_disp >= 0.35))
    row = int(np.flatnonzero(aligned.sample_index == 100)[0])
    assert not aligned.valid[row, 1] and aligned.valid[row, 0]
    assert np.isfinite(aligned.temperature).all()
    rows = np.arange(aligned.t.size)
    # temperature interpolated onto the displacement stamps
    T = aligned.temperature_at(rows, np.array([0]))[0]
    np.testing.assert_allclose(T, 44 + 0.1 * (aligned.t + aligned.start_time), atol=1e-9)
    np.testing.assert_allclose(aligned.temperature_rate, 0.1, atol=1e-9)
    # zero-order hold: each sample sees the command stamped half a period before it
    np.testing.assert_array_equal(aligned.command_index(rows), aligned.sample_index)


def test_split_interleaves_training_and_heldout_blocks() -> None:
    aligned = align(_measured())
    changes = np.flatnonzero(np.diff(aligned.train.astype(int)))
    assert changes.size >= 3  # more than a single cut
    first, second = aligned.train[: aligned.t.size // 2], aligned.train[aligned.t.size // 2 :]
    for half in (first, second):
        assert 0.3 < half.mean() < 0.7


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (
            lambda d: MeasuredData(
                d.command_times,
                d.command[:, :1],
                d.displacement_times,
                d.displacement,
                d.temperature_times,
                d.temperature,
            ),
            "mismatched grid sizes",
        ),
        (
            lambda d: MeasuredData(
                d.command_times[:50],
                d.command[:50],
                d.displacement_times[:50],
                d.displacement[:50],
                d.temperature_times,
                d.temperature,
            ),
            "too short",
        ),
        (
            lambda d: MeasuredData(
                d.command_times,
                d.command,
                d.displacement_times,
                d.displacement * np.nan,
                d.temperature_times,
                d.temperature,
            ),
            "too short",
        ),
    ],
)
def test_bad_measurements_raise_one_readable_line(mutate, message: str) -> None:
    with pytest.raises(CalibrationInputError, match=message) as err:
        align(mutate(_measured()))
    assert "\n" not in str(err.value)


def test_noise_floor_and_autocorrelation_time_of_white_and_smooth_residuals() -> None:
    rng = np.random.default_rng(6)
    t = np.arange(5000) / 500.0
    white = 0.5e-9 * rng.standard_normal((4, t.size))
    smooth = 3e-9 * np.sin(2 * np.pi * 1.0 * t)
    contiguous = np.ones(t.size - 1, bool)
    assert noise_floor(white + smooth, contiguous) == pytest.approx(0.5e-9, rel=0.05)
    assert integrated_autocorrelation_time(white, contiguous) < 1.5
    assert integrated_autocorrelation_time(white + smooth, contiguous) > 10.0


def test_drive_lowpass_is_exact_for_a_ramp_and_its_log_tau_slope_matches() -> None:
    h, tau, slope = 0.01, 0.3, np.array([2.0, -5.0])
    t = np.arange(200) * h
    x = 1.0 + slope[None, :] * t[:, None]
    y, d_log_tau = first_order_lowpass(x, h, tau)
    # tau y' + y = x from y(0) = x(0): y = x - tau m (1 - exp(-t / tau))
    exact = x - tau * slope[None, :] * (1.0 - np.exp(-t / tau))[:, None]
    np.testing.assert_allclose(y, exact, rtol=1e-12, atol=1e-12)
    step = 1e-6
    up = first_order_lowpass(x, h, tau * np.exp(step))[0]
    down = first_order_lowpass(x, h, tau * np.exp(-step))[0]
    np.testing.assert_allclose(d_log_tau, (up - down) / (2 * step), rtol=1e-6, atol=1e-9)
    with pytest.raises(ValueError, match="tau > 0"):
        first_order_lowpass(x, h, 0.0)
    # a time constant so long that the pole rounds to 1: the output holds the start
    y, d_log_tau = first_order_lowpass(x, h, 1e30)
    np.testing.assert_allclose(y, np.broadcast_to(x[:1], x.shape))
    assert np.all(np.isfinite(d_log_tau))


def test_only_offered_parameters_can_be_fitted_per_actuator() -> None:
    with pytest.raises(EffectError, match=r"drift\.fraction cannot be fitted per actuator"):
        CompositeModel(("drift",), per_actuator=("drift.fraction",))
    with pytest.raises(EffectError, match=r"sensor_lag\.tau_s"):
        CompositeModel(("drift",), per_actuator=("sensor_lag.tau_s",))  # effect not chosen
    model = CompositeModel(("self_heating",), per_actuator=("self_heating.gain",))
    assert model.global_names == ("self_heating.log_tau_s", "self_heating.log_mean_window_s")


@pytest.mark.parametrize("backend", ["numpy", "fused"])
def test_drive_history_computes_a_signals_slopes_once_for_every_time_constant(
    monkeypatch: pytest.MonkeyPatch, backend: str
) -> None:
    # A fit varies tau; the drive signal's slopes by its own parameters do not depend on it.
    # Fused, the signal and its slopes come from one compiled pass (model/heating_loop.py).
    import es_calibration.model.heating_loop as heating_loop

    monkeypatch.setenv(KERNELS_ENV, backend)
    effect = get_effect("self_heating")
    rng = np.random.default_rng(3)
    period, shape = 0.002, (float(np.log(0.5)),)
    command = 100.0 + 20.0 * rng.standard_normal((400, 3))
    direct = effect.drive_signal_slopes(command, period, shape)
    calls = []
    numpy_slopes = type(effect).drive_signal_slopes
    fused = heating_loop.fused_drive_signal

    def counted(self: object, *args: object) -> tuple[np.ndarray, ...]:
        calls.append(args)
        return numpy_slopes(self, *args)  # type: ignore[arg-type]

    def counted_fused(*args: Any) -> Any:
        calls.append(args)
        return fused(*args)

    history = DriveHistory(command, period)
    monkeypatch.setattr(type(effect), "drive_signal_slopes", counted)
    monkeypatch.setattr(heating_loop, "fused_drive_signal", counted_fused)
    for tau in (0.05, 0.2, 1.0):
        _, _, slopes = history.lowpass(effect, tau, shape)
        # the same numbers as filtering the slopes computed afresh
        for got, want in zip(slopes, direct, strict=True):
            np.testing.assert_array_equal(got, first_order_lowpass(want, period, tau)[0])
    assert len(calls) == 1
