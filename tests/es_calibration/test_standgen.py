"""The independent test-stand generator (testing/standgen): physics, operators, effects, bags."""

from __future__ import annotations

import math
from dataclasses import replace
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.integrate import trapezoid
from standgen import (
    FAULT_FAMILIES,
    UNLISTED_FAMILIES,
    Recording,
    StandBagError,
    StandConfig,
    StandConfigError,
    simulate,
    write_bag,
)
from standgen.effects import (
    Coupling,
    Delay,
    Drift,
    Effects,
    EffectSetError,
    Hysteresis,
    SelfHeating,
    SensorLag,
    TemperatureCurvature,
    ThermalExpansion,
    draw_effects,
)
from standgen.faults import (
    ActuatorFault,
    ClockRate,
    FaultError,
    Faults,
    ReceiveJitter,
    SensorFault,
    draw_fault,
)
from standgen.operators import (
    aging_gain,
    debye_relaxation,
    first_order_lag,
    laplacian,
    play,
    prandtl_ishlinskii,
)
from standgen.physics import Law
from standgen.program import Segment, VoltageProgram, make_independent_program
from standgen.ranges import (
    FAMILIES,
    FAULT_RANGES,
    RANGES,
    UNLISTED_RANGES,
    markdown_table,
    range_of,
)
from standgen.stand import drive
from standgen.unlisted import (
    AmplifierDroop,
    Creep,
    PeriodicNonlinearity,
    SlewLimit,
    ThermalGradient,
    Unlisted,
    UnlistedError,
    crept,
    depth,
    draw_unlisted,
    drooped,
    periodic_error,
    slew_limited,
)

from es_msgs_py.bag import read_bag

# --- the hyperbolic law against physics.md's reference numbers ------------------------------


def test_law_reference_numbers_at_40_degc() -> None:
    law = Law()
    assert float(law.d_max(40.0)) == pytest.approx(0.966e-9, rel=2e-3)
    assert float(law.v_max(40.0)) == pytest.approx(116.0, rel=5e-3)
    assert float(law.z_sat(40.0)) == pytest.approx(221e-9, rel=5e-3)


def test_law_shape_slope_and_symmetry() -> None:
    law = Law()
    v = np.linspace(0.0, 350.0, 35001)
    z = law.displacement(v, 40.0)
    slope = np.gradient(z, v)
    # the slope peaks at V_max with value d_max, where z = z_sat / 3
    assert v[np.argmax(slope)] == pytest.approx(float(law.v_max(40.0)), abs=0.05)
    assert slope.max() == pytest.approx(float(law.d_max(40.0)), rel=1e-6)
    assert float(law.displacement(law.v_max(40.0), 40.0)) == pytest.approx(
        float(law.z_sat(40.0)) / 3, rel=1e-12)
    assert np.all(np.diff(z) > 0) and z[-1] < float(law.z_sat(40.0))
    np.testing.assert_allclose(law.displacement(-v, 40.0), z, rtol=0, atol=0)
    # M falls by about 2.8 %/degC near 40 degC; the gain falls with temperature
    assert float(law.M(41.0) / law.M(40.0)) - 1 == pytest.approx(-0.028, abs=0.002)
    assert float(law.displacement(100.0, 52.0)) < float(law.displacement(100.0, 40.0))


def test_law_quadratic_terms_enter_at_t_star_squared() -> None:
    law = Law(m3=0.3e-18, k3=-0.2e-9)
    ts = 50.0 - law.Tm
    assert float(law.M(50.0)) == pytest.approx(Law().M(50.0) + 0.3e-18 * ts**2, rel=1e-12)
    assert float(law.k(50.0)) == pytest.approx(Law().k(50.0) - 0.2e-9 * ts**2, rel=1e-12)
    assert float(law.M(law.Tm)) == pytest.approx(1504e-18)


# --- operators ------------------------------------------------------------------------------


def _triangle(peaks: list[float], n: int = 200) -> np.ndarray:
    return np.concatenate([np.linspace(a, b, n, endpoint=False) for a, b in pairwise(peaks)]
                          + [np.array(peaks[-1:])])


def test_play_operator_is_bounded_by_its_threshold_and_holds_on_reversal() -> None:
    x = _triangle([0.0, 100.0, 60.0, 120.0, -50.0, 30.0])
    out = play(x, [10.0, 25.0])
    assert out.shape == (2, x.size)
    for r, p in zip((10.0, 25.0), out, strict=True):
        assert np.max(np.abs(x - p)) <= r + 1e-12
        assert np.max(np.abs(x - p)) == pytest.approx(r, rel=1e-2)  # the band is used fully
    # after the peak at 100 the input falls by 40 > 2 * 10: the narrow operator follows down,
    # a band of 2 * 25 = 50 > 40 keeps the wide one at 100 - 25 until the input rises again
    peak = int(np.argmax(x[:300]))
    assert out[1, peak + 150] == pytest.approx(75.0)
    assert out[0, peak + 199] == pytest.approx(x[peak + 199] + 10.0, abs=1e-9)


def test_play_operator_is_monotone_on_monotone_input_and_its_loops_close() -> None:
    rising = np.linspace(-200.0, 200.0, 1001)
    assert np.all(np.diff(play(rising, [30.0])[0]) >= 0)
    t = np.linspace(0.0, 3.0, 3001)
    x = 150.0 * np.sin(2 * np.pi * t)
    p = play(x, [20.0, 50.0])
    # periodic input: from the second period on the output repeats (closed loops)
    np.testing.assert_allclose(p[:, 1000:2000], p[:, 2000:3000], atol=1e-9)
    # at the same input x = 0 the rising branch sits r below, the falling branch r above
    assert p[0, 2000] == pytest.approx(-20.0) and p[0, 1500] == pytest.approx(20.0)
    assert p[1, 2000] == pytest.approx(-50.0) and p[1, 1500] == pytest.approx(50.0)


def test_prandtl_ishlinskii_with_n_operators() -> None:
    t = np.linspace(0.0, 2.0, 4001)
    x = 100.0 + 150.0 * np.sin(2 * np.pi * t)
    np.testing.assert_allclose(prandtl_ishlinskii(x, [20.0], [0.0]), x)
    thresholds, weights = [10.0, 30.0, 50.0], [0.02, 0.03, 0.05]
    y = prandtl_ishlinskii(x, thresholds, weights)
    plays = play(x, thresholds)
    np.testing.assert_allclose(y, 0.9 * x + 0.02 * plays[0] + 0.03 * plays[1] + 0.05 * plays[2])
    assert float(np.max(np.abs(y - x))) <= sum(w * r for w, r in zip(weights, thresholds,
                                                              strict=True)) + 1e-9
    # loop area: integral of y dx over a closed period is nonzero (energy lost per cycle)
    second = slice(2000, 4001)
    area = float(trapezoid(y[second], x[second]))  # scipy's: numpy < 2 has no np.trapezoid
    assert abs(area) > 100.0
    # per-actuator thresholds broadcast over a grid
    grid = np.stack([x, x], axis=1)[:, :, None]
    per = prandtl_ishlinskii(grid, np.array([[[10.0], [40.0]]]), np.array([[[0.1], [0.1]]]))
    np.testing.assert_allclose(per[:, 0, 0], prandtl_ishlinskii(x, [10.0], [0.1]))
    np.testing.assert_allclose(per[:, 1, 0], prandtl_ishlinskii(x, [40.0], [0.1]))
    with pytest.raises(ValueError, match="weights"):
        prandtl_ishlinskii(x, [10.0], [-0.1])
    with pytest.raises(ValueError, match="thresholds"):
        play(x, [-1.0])


def test_fractional_delay_is_exact_on_a_sine() -> None:
    rate, f, amp, phase = 500.0, 7.0, 120.0, 0.3
    seg = Segment("sine", 0.0, 5.0, np.full((1, 1), 20.0), (f,), np.full((1, 1, 1), amp),
                  np.full((1, 1, 1), phase))
    program = VoltageProgram((seg,))
    t = np.arange(2500) / rate
    for samples in (0.3, 1.2, 7.65):
        d = samples / rate
        config = StandConfig(rate_hz=rate, effects=Effects(delay=Delay(d)))
        v = drive(config, program, t)[:, 0, 0]
        np.testing.assert_allclose(v, 20.0 + amp * np.sin(2 * np.pi * f * (t - d) + phase),
                                   rtol=0, atol=1e-9)
        # and it is not the nearest whole-sample delay
        whole = 20.0 + amp * np.sin(2 * np.pi * f * (t - round(samples) / rate) + phase)
        assert np.max(np.abs(v - whole)) > 1.0


def test_first_order_lag_matches_the_exponential_step_response() -> None:
    dt, tau = 0.01, 0.5
    x = np.ones(300)
    x[0] = 0.0
    y = first_order_lag(x, dt, tau)
    k = np.arange(300)
    np.testing.assert_allclose(y[1:], 1 - np.exp(-k[1:] * dt / tau), rtol=1e-12)
    np.testing.assert_allclose(first_order_lag(x, dt, 0.0), x)


def test_debye_relaxation_gain_falls_with_frequency() -> None:
    dt = 1e-3
    t = np.arange(20000) * dt

    def gain(f: float) -> float:
        y = debye_relaxation(np.sin(2 * np.pi * f * t), dt, 0.1, 5.0)
        return float(np.sqrt(2) * np.std(y[10000:]))

    assert gain(0.1) == pytest.approx(1.0, abs=2e-3)
    assert gain(5.0) < gain(1.0) < 1.0
    assert gain(200.0) == pytest.approx(0.9, abs=2e-3)


def test_aging_gain_and_laplacian() -> None:
    assert float(aging_gain(0.0, 0.05, 10.0, 0.8)) == 1.0
    assert float(aging_gain(10.0, 0.05, 10.0, 0.8)) == pytest.approx(0.95 + 0.05 / math.e)
    assert float(aging_gain(1e6, 0.05, 10.0, 0.8)) == pytest.approx(0.95)
    z = np.zeros((3, 4))
    z[1, 1] = 1.0
    lap = laplacian(z)
    assert lap[1, 1] == -4.0 and lap[0, 1] == lap[2, 1] == lap[1, 0] == lap[1, 2] == 1.0
    assert lap.sum() == pytest.approx(0.0)
    corner = np.zeros((3, 4))
    corner[0, 0] = 1.0
    assert laplacian(corner)[0, 0] == -2.0
    np.testing.assert_allclose(laplacian(np.full((2, 5, 5), 3.0)), 0.0)


# --- effect sets and ranges -----------------------------------------------------------------


def test_drawn_effects_stay_in_their_documented_ranges() -> None:
    rng = np.random.default_rng(0)
    lo, hi = range_of("delay", "delay_samples").low, range_of("delay", "delay_samples").high
    for rate in (250.0, 5000.0):
        for _ in range(200):
            e = draw_effects(FAMILIES, rng, rate_hz=rate, duration_s=40.0, shape=(2, 2))
            assert e.names == FAMILIES
            assert e.delay is not None and e.hysteresis is not None
            samples = e.delay.delay_s * rate
            assert lo <= samples <= hi and 0.15 <= samples % 1 <= 0.85
            w, r = np.array(e.hysteresis.weights), np.array(e.hysteresis.thresholds_v)
            assert 1 <= w.size <= 3 and np.all(w >= 0) and 0.04 <= w.sum() <= 0.15
            assert np.all(np.diff(r) > 0) and r.min() >= 5.0 and r.max() <= 60.0
    assert {row.family for row in RANGES} == set(FAMILIES)
    assert all(f"`{f}`" in markdown_table() for f in FAMILIES)
    readme = (Path(__file__).resolve().parents[2] / "testing" / "standgen" / "README.md")
    assert markdown_table() in readme.read_text()
    with pytest.raises(EffectSetError, match="coupling"):
        draw_effects(["coupling"], rng, rate_hz=500.0, duration_s=40.0, shape=(1, 1))
    with pytest.raises(EffectSetError, match="unknown"):
        draw_effects(["backlash"], rng, rate_hz=500.0, duration_s=40.0, shape=(2, 2))
    with pytest.raises(StandConfigError, match="coupling"):
        simulate(StandConfig(effects=Effects(coupling=Coupling(0.05))))


# --- recordings ----------------------------------------------------------------------------

BASE = StandConfig(rows=2, cols=2, rate_hz=500.0, temperature_rate_hz=10.0, duration_s=20.0,
                   noise_m=0.5e-9, seed=7)


def _command_at(rec: Recording, times: np.ndarray) -> np.ndarray:
    idx = np.searchsorted(rec.command_times, times)
    assert np.all(rec.command_times[idx] == times)
    return np.asarray(rec.command[idx])


def test_clean_recording_follows_the_hyperbolic_law_within_noise() -> None:
    rec = simulate(BASE)
    v = _command_at(rec, rec.displacement_times)
    predicted = rec.law.displacement(v, rec.actuator_temperature)
    np.testing.assert_allclose(rec.truth_displacement, predicted, rtol=1e-12, atol=0)
    residual = rec.displacement - predicted
    assert np.std(residual) == pytest.approx(BASE.noise_rms_m, rel=0.05)
    assert abs(np.mean(residual)) < 0.05e-9
    # the drive spans the amplifier's range and the Peltier ramps 40 -> 52 -> 40
    assert np.abs(rec.command).max() <= 350.0 and np.ptp(rec.command) > 200.0
    assert rec.actuator_temperature.min() < 41.0 and rec.actuator_temperature.max() > 51.0
    assert rec.temperature.shape == (rec.temperature_times.size, 4)
    assert np.all(np.abs(np.round(rec.temperature / 0.01) * 0.01 - rec.temperature) < 1e-9)


def _with(**effects: Any) -> tuple[Recording, Recording]:
    clean = simulate(BASE)
    return clean, simulate(replace(BASE, effects=Effects(**effects)))


def test_each_effect_leaves_its_signature() -> None:
    clean, rec = _with(delay=Delay(2.0 / BASE.rate_hz))
    v = _command_at(clean, clean.displacement_times)
    idx = np.searchsorted(clean.command_times, clean.displacement_times)
    keep = idx >= 2
    delayed = clean.command[idx[keep] - 2]
    np.testing.assert_allclose(rec.truth_displacement[keep],
                               clean.law.displacement(
                                   delayed, clean.actuator_temperature[keep]),
                               rtol=1e-9, atol=1e-18)
    assert not np.allclose(rec.truth_displacement,
                           clean.law.displacement(v, clean.actuator_temperature))

    clean, rec = _with(thermal_expansion=ThermalExpansion(0.5e-9))
    np.testing.assert_allclose(
        rec.truth_displacement - clean.truth_displacement,
        0.5e-9 * (clean.actuator_temperature - 40.0), rtol=1e-9, atol=1e-20)

    clean, rec = _with(coupling=Coupling(0.05))
    diff = rec.truth_displacement - clean.truth_displacement
    np.testing.assert_allclose(diff, 0.05 * laplacian(clean.truth_displacement),
                               rtol=1e-9, atol=1e-22)
    np.testing.assert_allclose(diff.sum(axis=(1, 2)), 0.0, atol=1e-21)

    clean, rec = _with(drift=Drift(0.05, 5.0, 1.0))
    t = clean.displacement_times
    np.testing.assert_allclose(rec.truth_displacement,
                               clean.truth_displacement
                               * (0.95 + 0.05 * np.exp(-t / 5.0))[:, None, None], rtol=1e-9)

    clean, rec = _with(temperature_curvature=TemperatureCurvature(0.3e-18, 0.2e-9))
    law = replace(clean.law, m3=0.3e-18, k3=0.2e-9)
    np.testing.assert_allclose(rec.truth_displacement,
                               law.displacement(v, clean.actuator_temperature),
                               rtol=1e-12)

    clean, rec = _with(sensor_lag=SensorLag(2.0))
    np.testing.assert_array_equal(rec.truth_displacement,
                                  clean.truth_displacement)
    rising = (clean.temperature_times > 2.0) & (clean.temperature_times < 7.0)
    lag = clean.temperature[rising] - rec.temperature[rising]
    ramp = 12.0 / (0.4 * BASE.duration_s)  # degC/s of the Peltier ramp
    assert np.mean(lag) == pytest.approx(2.0 * ramp, rel=0.2)  # a lag reads tau * slope low

    clean, rec = _with(self_heating=SelfHeating(2e-5, 1.0))
    excess = rec.actuator_temperature - clean.actuator_temperature
    assert excess.min() >= 0.0 and excess.max() > 0.2
    np.testing.assert_array_equal(rec.temperature, clean.temperature)
    assert np.all(rec.truth_displacement <= clean.truth_displacement + 1e-18)

    clean, rec = _with(hysteresis=Hysteresis((15.0, 40.0), (0.05, 0.05)))
    diff = rec.truth_displacement - clean.truth_displacement
    assert np.std(diff) > 1e-9
    # the effective drive is within sum(w r) = 2.75 V of the command: a bounded change
    d_max = float(Law().d_max(40.0))
    assert np.max(np.abs(diff)) < 1.5 * d_max * 2.75


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bags_are_readable_by_our_reader_and_by_rosbags(tmp_path: Path, storage: str) -> None:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    config = replace(BASE, duration_s=8.0, drop_fraction=0.02, temperature_gap=(2.0, 1.5),
                     command_holes=((5.0, 0.1),), temperature_kind="raw_single")
    rec = simulate(config)
    counts = write_bag(rec, tmp_path / "bag", storage)
    with pytest.raises(StandBagError, match="exists"):
        write_bag(rec, tmp_path / "bag", storage)
    series = read_bag(tmp_path / "bag")
    assert counts == {t: len(s) for t, s in series.items()}
    got = series["/dm/displacement"].values
    assert got is not None
    np.testing.assert_array_equal(got, rec.displacement)
    got = series["/dm/command"].values
    assert got is not None
    np.testing.assert_array_equal(got, rec.command)
    got = series["/dm/temperature/raw"].values
    assert got is not None
    np.testing.assert_array_equal(got, rec.temperature)
    np.testing.assert_allclose(series["/dm/command"].times - config.start_time_s,
                               rec.command_times, atol=1e-6)

    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(tmp_path / "bag") as reader:
        msgs: dict[str, list[tuple[int, Any]]] = {}
        for conn, stamp, raw in reader.messages():
            msgs.setdefault(conn.topic, []).append((stamp, store.deserialize_cdr(raw,
                                                                                 conn.msgtype)))
    first = msgs["/dm/displacement"][0][1]
    assert [(d.label, d.size, d.stride) for d in first.layout.dim] == [
        ("row", 2, 4), ("col", 2, 2)]
    np.testing.assert_array_equal(first.data, rec.displacement[0].ravel())
    sensor = msgs["/dm/temperature/raw"][0][1]
    assert [(d.label, d.size, d.stride) for d in sensor.layout.dim] == [("sensor", 1, 1)]
    stamps = [s for topic in msgs.values() for s, _ in topic]
    assert len(stamps) == sum(counts.values())

    # the defects are really there
    n = round(config.duration_s * config.rate_hz)
    dropped = 1 - rec.displacement_times.size / n
    assert 0.005 < dropped < 0.04
    assert np.max(np.diff(rec.temperature_times)) == pytest.approx(1.6, abs=0.11)
    hole = np.max(np.diff(rec.command_times))
    assert hole == pytest.approx(0.1 + 1 / config.rate_hz, abs=1.1 / config.rate_hz)


def test_grid_temperature_topic_and_bad_storage(tmp_path: Path) -> None:
    rec = simulate(replace(BASE, duration_s=4.0, temperature_kind="grid"))
    assert rec.temperature_topic == "/dm/temperature" and rec.temperature.ndim == 3
    write_bag(rec, tmp_path / "bag")
    values = read_bag(tmp_path / "bag")["/dm/temperature"].values
    assert values is not None and values.shape[1:] == (2, 2)
    with pytest.raises(StandBagError, match="storage"):
        write_bag(rec, tmp_path / "other", "rosbag1")


# --- recording faults (issue 33) -------------------------------------------------------------

GRID4 = replace(BASE, rows=4, cols=4)


def test_fault_and_unlisted_tables_are_in_the_readme_and_draws_refuse_what_cannot_show() -> None:
    assert {row.family for row in FAULT_RANGES} == set(FAULT_FAMILIES)
    assert {row.family for row in UNLISTED_RANGES} == set(UNLISTED_FAMILIES)
    assert not set(UNLISTED_FAMILIES) & set(FAMILIES)  # in no list of the registry
    readme = (Path(__file__).resolve().parents[2] / "testing" / "standgen" / "README.md")
    text = readme.read_text()
    assert markdown_table(FAULT_RANGES) in text and markdown_table(UNLISTED_RANGES) in text
    rng = np.random.default_rng(0)
    with pytest.raises(FaultError, match="4 sensors"):
        draw_fault("sensor_frozen", rng, rate_hz=500.0, duration_s=20.0, sensors=1, cells=4)
    with pytest.raises(FaultError, match="unknown"):
        draw_fault("gremlin", rng, rate_hz=500.0, duration_s=20.0, sensors=4, cells=4)
    with pytest.raises(UnlistedError, match="3 x 3"):
        draw_unlisted(["thermal_gradient"], rng, (2, 2))
    with pytest.raises(UnlistedError, match="unknown"):
        draw_unlisted(["backlash"], rng, (2, 2))
    with pytest.raises(StandConfigError, match="sensor"):
        simulate(replace(BASE, faults=Faults(sensor=SensorFault("flat", 4, 0.0, 25.0))))
    with pytest.raises(StandConfigError, match="actuator"):
        simulate(replace(BASE, faults=Faults(actuator=ActuatorFault("dead", -1, 0.0))))
    for family in FAULT_FAMILIES:  # every family draws inside its table's rows
        faults = draw_fault(family, rng, rate_hz=500.0, duration_s=20.0, sensors=16, cells=16)
        names = faults.names
        assert names == (() if family == "independent_drive" else (family,))
        for name, truth in faults.as_dict().items():
            assert name == family and truth


def test_clock_rate_fault_drifts_the_displacement_stamps_by_its_ppm(tmp_path: Path) -> None:
    clean = simulate(BASE)
    rec = simulate(replace(BASE, faults=Faults(clock_rate=ClockRate(60.0))))
    np.testing.assert_array_equal(rec.displacement_sample_times, clean.displacement_times)
    np.testing.assert_array_equal(rec.displacement, clean.displacement)
    np.testing.assert_array_equal(rec.command_times, clean.command_times)
    t, stamps = rec.displacement_sample_times, rec.displacement_times
    np.testing.assert_allclose((stamps - t)[1:] / t[1:], 60e-6, rtol=1e-9)
    assert stamps[-1] - t[-1] == pytest.approx(60e-6 * 20.0, rel=0.01)  # 1.2 ms after 20 s
    write_bag(rec, tmp_path / "bag")
    times = read_bag(tmp_path / "bag")["/dm/displacement"].times - BASE.start_time_s
    np.testing.assert_allclose(times, stamps, atol=2e-6)


@pytest.mark.parametrize("kind", ["frozen", "flat", "jump"])
def test_sensor_faults_change_only_their_sensor(kind: str) -> None:
    fault = {"frozen": SensorFault("frozen", 5, 9.0),
             "flat": SensorFault("flat", 5, 0.0, value_degc=24.5),
             "jump": SensorFault("jump", 5, 6.0, jumps=((6.0, 2.0), (13.0, -1.5)))}[kind]
    clean = simulate(GRID4)
    rec = simulate(replace(GRID4, faults=Faults(sensor=fault)))
    assert rec.temperature.shape == clean.temperature.shape == (clean.temperature_times.size, 16)
    others = np.arange(16) != 5
    np.testing.assert_array_equal(rec.temperature[:, others], clean.temperature[:, others])
    np.testing.assert_array_equal(rec.displacement, clean.displacement)
    t, mine, was = rec.temperature_times, rec.temperature[:, 5], clean.temperature[:, 5]
    if kind == "frozen":
        after = t >= 9.0
        np.testing.assert_array_equal(mine[~after], was[~after])
        assert np.all(mine[after] == was[~after][-1])  # constant after the freeze ...
        assert np.ptp(was[after]) > 1.0  # ... while the mount's temperature moved
    elif kind == "flat":
        assert np.all(mine == 24.5)
    else:
        steps = np.where(t >= 13.0, 0.5, np.where(t >= 6.0, 2.0, 0.0))
        np.testing.assert_allclose(mine - was, steps, atol=1e-9)


@pytest.mark.parametrize("kind", ["weak", "dead"])
def test_weak_and_dead_actuators_move_their_fraction(kind: str) -> None:
    fraction = 0.6 if kind == "weak" else 0.0
    clean = simulate(GRID4)
    rec = simulate(replace(GRID4, faults=Faults(actuator=ActuatorFault(kind, 6, fraction))))
    z, z0 = rec.truth_displacement.reshape(-1, 16), clean.truth_displacement.reshape(-1, 16)
    np.testing.assert_allclose(z[:, 6], fraction * z0[:, 6], rtol=1e-12, atol=0)
    others = np.arange(16) != 6
    np.testing.assert_array_equal(z[:, others], z0[:, others])
    np.testing.assert_array_equal(rec.law.m2, clean.law.m2)  # the fault is not the law's
    if kind == "dead":  # the interferometer sees only its noise
        assert np.std(rec.displacement.reshape(-1, 16)[:, 6]) == pytest.approx(
            GRID4.noise_rms_m, rel=0.1)
        assert np.ptp(z0[:, 6]) > 50e-9


def test_receive_jitter_delays_stamps_and_delivers_bursts_late_in_order() -> None:
    jitter = ReceiveJitter(mean_s=1e-3, bursts=((5.0, 0.2, 0.08), (12.0, 0.15, 0.05)))
    rec = simulate(replace(BASE, faults=Faults(receive_jitter=jitter)))
    t, stamps = rec.displacement_sample_times, rec.displacement_times
    late = stamps - t
    assert np.all(late >= 0) and np.all(np.diff(stamps) >= 0)  # received in sample order
    for start, length, lateness in jitter.bursts:
        inside = (t >= start) & (t < start + length)
        assert inside.sum() > 0.9 * length * BASE.rate_hz
        np.testing.assert_allclose(stamps[inside], start + length + lateness, atol=1e-3)
    quiet = (t < 4.5) | ((t > 6.0) & (t < 11.5)) | (t > 13.0)
    assert np.mean(late[quiet]) == pytest.approx(1e-3, rel=0.15)
    np.testing.assert_array_equal(rec.command_times,
                                  simulate(BASE).command_times)  # the command keeps its clock


def test_independent_drive_gives_every_actuator_its_own_edges() -> None:
    rng = np.random.default_rng(3)
    program = make_independent_program(rng, 20.0, (2, 3), 500.0)
    starts = [tuple(s.start for s in p.segments) for p in program.programs]
    assert len(set(starts)) == 6  # no two actuators share their segment edges
    t = np.arange(0.0, 20.0, 1 / 500.0)
    v = program(t)
    assert v.shape == (t.size, 2, 3)
    np.testing.assert_array_equal(v[:, 1, 2], program.programs[5](t)[:, 0, 0])
    rec = simulate(replace(GRID4, independent_drive=True))
    assert rec.command.shape == (rec.command_times.size, 4, 4)
    assert not np.allclose(rec.command, simulate(GRID4).command)


# --- effects in no list of the registry (issue 34) -------------------------------------------


def test_slew_limit_and_droop_shape_the_amplifiers_output() -> None:
    dt = 1e-3
    t = np.arange(0.0, 1.0, dt)
    square = np.where((t % 0.2) < 0.1, 200.0, 0.0)[:, None]
    limited = slew_limited(square, dt, 5e3)
    assert np.max(np.abs(np.diff(limited, axis=0))) <= 5e3 * dt + 1e-9
    assert limited[-1, 0] == square[-1, 0] and limited.max() == 200.0  # it gets there, later
    sine = 100.0 * np.sin(2 * np.pi * 5.0 * t)[:, None]
    out = drooped(sine, dt, AmplifierDroop(0.05))
    rate = np.abs(np.gradient(sine, dt, axis=0))
    np.testing.assert_allclose(out, sine * (1 - 0.05 * np.minimum(rate / 5e3, 1)))
    clean = simulate(BASE)
    rec = simulate(replace(BASE, unlisted=Unlisted(slew_limit=SlewLimit(4e3))))
    assert np.sqrt(np.mean((rec.truth_displacement - clean.truth_displacement) ** 2)) > 1e-9
    np.testing.assert_array_equal(rec.command, clean.command)  # the command does not show it


def test_periodic_nonlinearity_is_in_the_measurement_not_the_mirror() -> None:
    error = PeriodicNonlinearity(1.0e-9, 0.3, 1.1)
    clean = simulate(BASE)
    rec = simulate(replace(BASE, unlisted=Unlisted(periodic_nonlinearity=error)))
    np.testing.assert_array_equal(rec.truth_displacement, clean.truth_displacement)
    np.testing.assert_allclose(rec.displacement - clean.displacement,
                               periodic_error(clean.truth_displacement, error),
                               atol=0.1e-9 + 1e-15)  # one quantisation step
    z = np.linspace(0.0, 633e-9 / 2, 1001)  # one fringe: one period of the first order
    e = periodic_error(z, error)
    assert e[0] == pytest.approx(e[-1], abs=1e-15) and np.ptp(e) > 1.5e-9


def test_creep_grows_by_its_gamma_per_decade_after_a_step() -> None:
    dt = 1e-3
    step = np.ones((30_000, 1))
    step[0] = 0.0
    z = crept(step, dt, Creep(0.02))[:, 0]
    t = np.arange(z.size) * dt
    growth = np.interp(1.0, t, z) - np.interp(0.1, t, z)  # one decade of time
    assert growth == pytest.approx(0.02, rel=0.3)
    assert np.all(np.diff(z[1:]) >= 0)  # creep only ever continues the step


def test_thermal_gradient_warms_the_centre_late_and_the_sensors_miss_it() -> None:
    clean = simulate(GRID4)
    rec = simulate(replace(GRID4, unlisted=Unlisted(thermal_gradient=ThermalGradient(1.0))))
    np.testing.assert_array_equal(rec.temperature, clean.temperature)
    offset = rec.actuator_temperature - clean.actuator_temperature
    rim = depth((4, 4)) == 0
    np.testing.assert_allclose(offset[:, rim], 0.0, atol=1e-12)
    t = rec.displacement_sample_times
    rising = (t > 3.0) & (t < 6.0)  # the Peltier ramps 12 degC over 8 s: ~1.5 degC/s
    centre = offset[rising][:, ~rim]
    assert np.all(centre < 0) and np.mean(centre) == pytest.approx(-1.5, rel=0.25)
