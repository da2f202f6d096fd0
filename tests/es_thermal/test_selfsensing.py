"""Self-sensing fusion and resonance calibration cores (pure, no DDS)."""

from __future__ import annotations

import numpy as np
import pytest

from es_thermal.resonance_calibration import (
    ResonanceCalibrationError,
    command_in_force,
    fit_resonance,
)
from es_thermal.selfsensing import (
    CalibrationError,
    FusionConfig,
    ResonanceCalibration,
    SelfSensingFusion,
)
from es_thermal.sweep_sync import MAX_WAITING, SampleSync

ROWS, COLS = 8, 8
N = ROWS * COLS
A_T, A_V, F0, T0 = 3227.0, -80.0, 1.0e6, 40.0


def calibration(**extra: object) -> ResonanceCalibration:
    return ResonanceCalibration.from_values(
        N, f0_hz=F0, a_t_hz_per_degc=A_T, a_v_hz_per_v=A_V, reference_temperature=T0,
        **extra,  # type: ignore[arg-type]
    )  # fmt: skip


def law(temperature: np.ndarray, voltage: np.ndarray) -> np.ndarray:
    return F0 + A_T * (temperature - T0) + A_V * np.abs(voltage)


def test_law_inverts_with_the_voltage_term() -> None:
    cal = calibration()
    temperature = np.linspace(35.0, 55.0, N)
    voltage = np.linspace(-300.0, 300.0, N)
    np.testing.assert_allclose(cal.temperature(law(temperature, voltage), voltage), temperature)
    with pytest.raises(CalibrationError, match="a_t"):
        ResonanceCalibration.from_values(
            N, f0_hz=F0, a_t_hz_per_degc=0.0, a_v_hz_per_v=A_V, reference_temperature=T0
        )
    with pytest.raises(CalibrationError, match="3 values"):
        ResonanceCalibration.from_values(
            N, f0_hz=[F0] * 3, a_t_hz_per_degc=A_T, a_v_hz_per_v=A_V, reference_temperature=T0
        )


def hot_spot() -> np.ndarray:
    """A non-uniform field: 42 degC plus a 1.5 degC off-centre hot spot."""
    r, c = np.meshgrid(np.arange(ROWS), np.arange(COLS), indexing="ij")
    return (42.0 + 1.5 * np.exp(-((r - 2.0) ** 2 + (c - 5.0) ** 2) / 6.0)).ravel()


def round_robin(cycle: int, groups: int, values: np.ndarray) -> np.ndarray:
    return np.where(np.arange(N) % groups == cycle % groups, values, np.nan)


def test_fusion_recovers_a_non_uniform_field_the_model_misses() -> None:
    rng = np.random.default_rng(7)
    truth = hot_spot()
    model = np.full(N, truth.mean())  # what a few sensors and the model see: smooth
    voltage = rng.uniform(0.0, 200.0, N)
    fusion = SelfSensingFusion(calibration(), FusionConfig(noise_hz=15.0, drift=0.01))
    fusion.set_command(voltage)
    for cycle in range(30):
        freq = law(truth, voltage) + 15.0 * rng.standard_normal(N)
        fused = fusion.fuse(0.1 * cycle, model, round_robin(cycle, 3, freq))
    model_rms = np.sqrt(np.mean((model - truth) ** 2))
    fused_rms = np.sqrt(np.mean((fused - truth) ** 2))
    assert model_rms > 0.3
    assert fused_rms < 0.01
    assert fused_rms < model_rms / 30
    health = fusion.latest
    assert health is not None and not health.implausible.any() and not health.stale.any()


def test_without_resonance_data_the_model_estimate_passes_unchanged() -> None:
    fusion = SelfSensingFusion(calibration(), FusionConfig())
    model = hot_spot().reshape(ROWS, COLS)
    for cycle in range(5):
        out = fusion.fuse(0.1 * cycle, model, None)
        np.testing.assert_array_equal(out, model)
    assert fusion.latest is not None and not fusion.latest.received


def test_implausible_and_stale_channels_are_dropped_and_reported() -> None:
    truth = np.full(N, 42.0)
    model = truth + 0.2  # model a little off everywhere
    fusion = SelfSensingFusion(
        calibration(), FusionConfig(noise_hz=10.0, stale_after=1.0), disabled=(7,)
    )
    freq = law(truth, np.zeros(N))
    freq[3] += 2.0e5  # an implausible channel (62 degC off)
    freq[4] = 5.0e4  # outside the plausible frequency range
    freq[5] = np.nan  # a channel that stops answering
    freq[7] += 1.0e4  # disabled by the calibration: never used
    fused = fusion.fuse(0.0, model, freq)
    health = fusion.latest
    assert health is not None
    assert set(np.flatnonzero(health.implausible)) == {3, 4}
    assert health.counts()["resonance_implausible"] == 2
    assert health.worst()["resonance_first_implausible"] == "3, 4"
    assert fused[3] == model[3] and fused[4] == model[4] and fused[7] == model[7]
    np.testing.assert_allclose(fused[0], 42.0, atol=0.02)  # a good channel corrects
    # channel 5 gives nothing for longer than stale_after: stale, correction dropped
    for k in range(1, 15):
        fused = fusion.fuse(0.1 * k, model, freq)
    health = fusion.latest
    assert health is not None
    assert set(np.flatnonzero(health.stale)) == {3, 4, 5}
    assert "resonance_first_stale" in health.worst()
    assert fused[5] == model[5]
    assert np.all(np.isfinite(fused))
    with pytest.raises(ValueError, match="expected 64"):
        fusion.fuse(2.0, model, freq[:10])
    with pytest.raises(ValueError, match="NaN"):
        fusion.set_command(np.full(N, np.nan))
    with pytest.raises(CalibrationError, match="disabled"):
        SelfSensingFusion(calibration(), FusionConfig(), disabled=(N,))


def synthetic_characterisation(rng: np.random.Generator, k: int = 600) -> tuple[np.ndarray, ...]:
    """An independent few-line generator: a ramp, random voltages, the law, noise."""
    f0 = F0 + 5e3 * rng.standard_normal((ROWS, COLS))
    a_t = A_T * (1 + 0.03 * rng.standard_normal((ROWS, COLS)))
    a_v = A_V * (1 + 0.1 * rng.standard_normal((ROWS, COLS)))
    stage = 40.0 + 12.0 * np.sin(np.linspace(0.0, np.pi, k))
    volts = rng.uniform(-300.0, 300.0, (k, ROWS, COLS))
    freq = f0 + a_t * (stage[:, None, None] - T0) + a_v * np.abs(volts)
    freq = freq + 20.0 * rng.standard_normal(freq.shape)
    freq[rng.random(freq.shape) < 0.5] = np.nan  # round robin: half unswept
    return f0, a_t, a_v, stage, volts, freq


def test_calibration_recovers_the_laws_within_their_uncertainties() -> None:
    rng = np.random.default_rng(11)
    f0, a_t, a_v, stage, volts, freq = synthetic_characterisation(rng)
    fit = fit_resonance(0.1 * np.arange(stage.size, dtype=float), freq, volts, stage, T0)
    assert fit.disabled == ()
    for value, truth, sd in (
        (fit.f0_hz, f0, fit.f0_sd_hz),
        (fit.a_t_hz_per_degc, a_t, fit.a_t_sd),
        (fit.a_v_hz_per_v, a_v, fit.a_v_sd),
    ):
        pull = (value - truth) / sd
        assert np.all(np.abs(pull) < 5.0)
        assert 0.7 < np.std(pull) < 1.4  # the uncertainties are honest
    assert fit.noise_hz == pytest.approx(20.0, rel=0.1)


def test_calibration_flags_dead_channels_and_rejects_unusable_data() -> None:
    rng = np.random.default_rng(12)
    _, _, _, stage, volts, freq = synthetic_characterisation(rng)
    freq[:, 0, 0] = np.nan  # never answers
    freq[:, 1, 1] = freq[0, 1, 1] if np.isfinite(freq[0, 1, 1]) else F0  # stuck
    fit = fit_resonance(0.1 * np.arange(stage.size, dtype=float), freq, volts, stage, T0)
    assert fit.disabled == (0, COLS + 1)
    assert np.all(np.isfinite(fit.f0_hz))
    with pytest.raises(ResonanceCalibrationError, match="ramp"):
        flat = np.full(stage.size, 40.0)
        fit_resonance(0.1 * np.arange(stage.size, dtype=float), freq, volts, flat, T0)
    with pytest.raises(ResonanceCalibrationError, match="line up"):
        fit_resonance(0.1 * np.arange(3, dtype=float), freq, volts, stage, T0)


def test_command_in_force_is_the_last_one_stamped_before() -> None:
    commands = np.arange(4, dtype=float)[:, None, None] * np.ones((4, 2, 2))
    times = np.array([0.0, 0.1, 0.2, 0.3])
    got = command_in_force(np.array([0.0, 0.1, 0.15, 0.5]), times, commands)
    np.testing.assert_array_equal(got[:, 0, 0], [0.0, 0.0, 1.0, 3.0])


def test_a_stuck_channel_is_dropped_once_the_model_moves() -> None:
    fusion = SelfSensingFusion(calibration(), FusionConfig(noise_hz=10.0, stuck_band_degc=0.3))
    rng = np.random.default_rng(4)
    frozen = law(np.full(N, 42.0), np.zeros(N))[9]
    for k in range(12):
        truth = np.full(N, 42.0 + 0.05 * k)  # everything warms by 0.55 degC
        freq = law(truth, np.zeros(N)) + 10.0 * rng.standard_normal(N)
        freq[9] = frozen  # channel 9 repeats its first reading
        fused = fusion.fuse(0.1 * k, truth + 0.1, freq)  # the model: 0.1 degC off
        health = fusion.latest
        assert health is not None
        if k <= 5:  # model moved < 0.3 degC: not yet told apart from a still channel
            assert not health.stuck[9]
    health = fusion.latest
    assert health is not None
    assert health.stuck[9] and health.counts()["resonance_stuck"] == 1
    assert health.worst()["resonance_first_stuck"] == "9"
    assert fused[9] == truth[9] + 0.1  # back to the model alone
    assert not health.stuck[np.arange(N) != 9].any()
    np.testing.assert_allclose(np.delete(fused, 9), np.delete(truth, 9), atol=0.03)


def test_a_sweep_is_fused_with_its_own_sample_and_command_in_any_order() -> None:
    truth = np.full(N, 42.0)
    truth[0] = 43.0  # the model misses actuator 0 by 1 degC
    model = np.full(N, 42.0)
    v1, v2 = np.full(N, 100.0), np.full(N, 130.0)
    sweep = law(truth, v1)  # swept under v1, published at 20 ns; v2 published at 30 ns
    # in order: command, sweep, readings, next command
    sync = SampleSync(SelfSensingFusion(calibration(), FusionConfig()), sample_period=0.1)
    sync.on_command(10, v1)
    sync.on_resonance(0.0, 20, sweep)
    sync.on_command(30, v2)
    assert sync.on_estimate(0.0, 0.0, model)[0] == pytest.approx(43.0, abs=1e-3)
    assert sync.paired == {"in_order": 1, "late": 0, "without_command": 0, "dropped": 0}
    # readings first, then the sweep, then the command it ran under arrives late (a backlog)
    # and the next one: fused against its own sample's model estimate and v1
    late = SampleSync(SelfSensingFusion(calibration(), FusionConfig()), sample_period=0.1)
    assert late.on_estimate(0.0, 0.0, model)[0] == 42.0
    late.on_resonance(0.01, 20, sweep)
    late.on_command(10, v1)
    late.on_command(30, v2)
    assert late.paired == {"in_order": 0, "late": 1, "without_command": 0, "dropped": 0}
    assert late.on_estimate(0.1, 0.1, model + 0.5)[0] == pytest.approx(43.5, abs=1e-3)
    assert late.health is not None and late.health.accepted[0]
    # no command after the sweep for longer than the window: fused with the newest one
    quiet = SampleSync(SelfSensingFusion(calibration(), FusionConfig()), sample_period=0.1)
    quiet.on_command(10, v1)
    quiet.on_resonance(0.0, 20, sweep)
    quiet.on_estimate(0.0, 0.0, model)
    quiet.on_estimate(0.2, 0.2, model)
    assert quiet.paired["without_command"] == 1
    assert quiet.fusion.correction[0] == pytest.approx(1.0, abs=1e-3)


def test_a_sweep_waits_for_its_command_behind_a_backlog_of_older_ones() -> None:
    """Commands still coming but far behind (a deep queue draining): never guess a command."""
    truth = np.full(N, 42.0)
    truth[0] = 43.0  # the model misses actuator 0 by 1 degC
    model = np.full(N, 42.0)
    v_old, v1, v2 = np.zeros(N), np.full(N, 150.0), np.full(N, 160.0)
    sweep = law(truth, v1)  # swept under v1 (published at 50 ns), published at 60 ns
    sync = SampleSync(SelfSensingFusion(calibration(), FusionConfig()), sample_period=0.1)
    sync.on_command(1, v_old, 0.0)
    sync.on_resonance(0.0, 60, sweep)
    sync.on_estimate(0.0, 0.0, model)
    # three sample periods on, the commands handled are still older than the sweep
    for k in range(1, 4):
        sync.on_command(1 + k, v_old, 0.1 * k - 0.01)
        assert sync.on_estimate(0.1 * k, 0.1 * k, model)[0] == 42.0
    assert sync.paired == {"in_order": 0, "late": 0, "without_command": 0, "dropped": 0}
    sync.on_command(50, v1, 0.35)
    sync.on_command(70, v2, 0.36)
    assert sync.paired == {"in_order": 0, "late": 1, "without_command": 0, "dropped": 0}
    assert sync.on_estimate(0.4, 0.4, model)[0] == pytest.approx(43.0, abs=1e-3)
    # the commands stop: a sweep overdue is then fused with the newest command after all
    sync.on_resonance(0.5, 80, law(truth, v2))
    sync.on_estimate(0.5, 0.5, model)
    sync.on_estimate(0.7, 0.7, model)
    assert sync.paired["without_command"] == 1
    assert sync.fusion.correction[0] == pytest.approx(1.0, abs=1e-3)


def test_sweeps_whose_command_never_comes_are_dropped_and_counted() -> None:
    """A command source whose stamps stay behind the sweeps' must not pile sweeps up."""
    sync = SampleSync(SelfSensingFusion(calibration(), FusionConfig()), sample_period=0.1)
    model = np.full(N, 42.0)
    sweep = law(model, np.zeros(N))
    for k in range(MAX_WAITING + 10):
        sync.on_command(k, np.zeros(N), 0.1 * k)  # always published before the sweeps
        sync.on_resonance(0.1 * k, 10_000 + k, sweep)
        sync.on_estimate(0.1 * k, 0.1 * k, model)
    assert sync.paired["dropped"] == 10
    assert sync.paired["late"] + sync.paired["in_order"] + sync.paired["without_command"] == 0
