"""The drive-dependent effects' shared pieces: relaxation filter and heating estimate."""

from __future__ import annotations

import numpy as np
import pytest

from es_physics.effects import FittedEffect
from es_physics.effects.frequency_dispersion import (
    FrequencyDispersion,
    relaxation_advance,
    relaxation_decay,
    relaxation_inverse,
    relaxation_output,
)
from es_physics.effects.self_heating import MEAN_WINDOW_S, HeatingEstimate, SelfHeating


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


def test_the_calibrations_loss_measure_is_the_heating_estimates() -> None:
    # a 2 Hz sine of 100 V around 150 V at 1 kHz for 10 s, on two actuators
    dt = 1e-3
    t = np.arange(0.0, 10.0, dt)
    command = 150.0 + 100.0 * np.sin(2 * np.pi * 2.0 * t)[:, None] * np.array([1.0, 0.5])
    loss = SelfHeating().drive_signal(command, dt)
    tau = 1e6
    estimate = HeatingEstimate(1.0, tau, MEAN_WINDOW_S)  # tau >> run: dT integrates P / tau
    for k, row in enumerate(command):
        estimate.apply(row, k * dt)
    # HeatingEstimate's excess with g = 1 is sum(P_k dt) / tau: the same measure P_k
    np.testing.assert_allclose(
        np.asarray(estimate.at((len(t) - 1) * dt)), loss[1:-1].sum(axis=0) * dt / tau, rtol=1e-4
    )
    # the measure's mean over the settled part is f A^2 (g f A^2 for a sine, see the module)
    settled = loss[t > 5.0].mean(axis=0)
    np.testing.assert_allclose(settled, 2.0 * np.array([100.0, 50.0]) ** 2, rtol=0.03)


def test_the_loss_measure_takes_the_fitted_window_and_its_slope() -> None:
    # a 2 Hz swing on a 0.2 Hz level at 1 kHz for 10 s: the level's share of the running
    # mean, and so the measure, depends on the window
    dt, window = 1e-3, 1.6
    t = np.arange(0.0, 10.0, dt)[:, None]
    command = 150.0 + 60.0 * np.sin(2 * np.pi * 0.2 * t) + 40.0 * np.sin(2 * np.pi * 2.0 * t)
    heating = SelfHeating()
    shape = (np.log(window),)
    loss = heating.drive_signal(command, dt, shape)
    estimate = HeatingEstimate(1.0, 1e6, window)  # the feedforward's measure, same window
    for k, row in enumerate(command):
        estimate.apply(row, k * dt)
    np.testing.assert_allclose(
        np.asarray(estimate.at((len(t) - 1) * dt)), loss[1:-1].sum(axis=0) * dt / 1e6, rtol=1e-4
    )
    assert not np.allclose(loss, heating.drive_signal(command, dt))  # the 1 s default
    (slope,) = heating.drive_signal_slopes(command, dt, shape)
    h = 1e-5
    numeric = (
        heating.drive_signal(command, dt, (shape[0] + h,))
        - heating.drive_signal(command, dt, (shape[0] - h,))
    ) / (2.0 * h)
    # the measure has a kink where the drive crosses its mean: a difference across it differs
    close = np.isclose(slope, numeric, rtol=1e-6, atol=1e-6 * np.abs(numeric).max())
    assert close.mean() > 0.999


def test_filter_effects_must_be_determined() -> None:
    heating, dispersion = SelfHeating(), FrequencyDispersion()
    good = FittedEffect(
        {"gain": 1e-5, "log_tau_s": 0.5, "log_mean_window_s": 0.4},
        {"gain": 1e-6, "log_tau_s": 0.1, "log_mean_window_s": 0.2},
    )
    assert heating.undetermined(good) is None
    loose = FittedEffect({"gain": 1e-4, "log_tau_s": 4.7}, {"gain": 5e-4, "log_tau_s": 3.0})
    assert "gain not determined" in str(heating.undetermined(loose))
    corner = FittedEffect(
        {"fraction": 0.08, "log_corner_hz": 1.8}, {"fraction": 0.01, "log_corner_hz": 1.5}
    )
    assert "log_corner_hz not determined" in str(dispersion.undetermined(corner))
    # reported in physical units, and what the feedforward gets from them
    reported = heating.reported(good)
    assert reported == {
        "gain": 1e-5,
        "tau_s": pytest.approx(np.exp(0.5)),
        "mean_window_s": pytest.approx(np.exp(0.4)),
    }
    assert heating.problem(reported) is None
    assert heating.problem({"gain": -1e-6, "tau_s": 1.0}) is not None
    comp = heating.compensation_values(reported, 0.0)
    assert comp["self_heating_gain"] == 1e-5
    assert comp["self_heating_mean_window_s"] == pytest.approx(np.exp(0.4))  # the fitted one
    assert dispersion.problem({"fraction": 0.95, "corner_hz": 5.0}) is not None


def test_a_play_operator_whose_weight_the_fit_cannot_tell_from_none_is_no_finding() -> None:
    from es_physics.effects.hysteresis import Hysteresis

    hysteresis = Hysteresis()
    found = FittedEffect({"weight": 0.05, "decay_per_degc": 0.1},
                         {"weight": 0.002, "decay_per_degc": 0.05})
    assert hysteresis.undetermined(found) is None
    # the independent stand's thermal gradient, taken by an operator at the drive's top
    loose = FittedEffect({"weight": 2.5e-4, "decay_per_degc": -0.16},
                         {"weight": 3.7e-4, "decay_per_degc": 0.5})
    assert str(hysteresis.undetermined(loose)) == "weight not determined (1-sigma 0.00037)"
    second = FittedEffect({"weight": 0.05, "weight_2": -1e-3, "decay_per_degc": 0.0},
                          {"weight": 0.002, "weight_2": 0.004, "decay_per_degc": 0.0})
    assert "weight_2 not determined" in str(hysteresis.undetermined(second))
