"""The fused kernels give the numpy path's numbers; the shortcut statuses equal the inverse's."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest

from es_feedforward import kernels
from es_feedforward.feedforward import (
    REACH_MARGIN,
    Feedforward,
    FeedforwardConfig,
    Mode,
    ObserverGains,
)
from es_feedforward.kernels import (
    KERNELS_ENV,
    Backend,
    KernelBackendError,
    default_backend,
    fused_available,
    fused_hyperbolic_inverse,
    fused_linearized,
    fused_reach_status,
    observer_command,
)
from es_physics.laws import CODE_CLIPPED_HIGH, CODE_OK, DEFAULT_V_LIMIT, LawsAtTemperature
from es_physics.params import ActuatorParams

SHAPE = (12, 16)
#: Temperatures [degC] from inside the laws' range to beyond it (clamped, flagged).
TEMPERATURES = (25.0, 40.0, 46.0, 52.0, 80.0)

#: Each mode once with the default gains, the observer also with a proportional part.
CASES = [(mode, ObserverGains()) for mode in Mode] + [
    (Mode.OBSERVER, ObserverGains(kp=0.3, ki=0.5, iterations=4))
]


def _params(rng: np.random.Generator) -> ActuatorParams:
    return ActuatorParams(
        m1=rng.uniform(-45e-18, -38e-18, SHAPE),
        m2=rng.uniform(1300e-18, 1700e-18, SHAPE),
        k1=rng.uniform(-19e-9, -16e-9, SHAPE),
        k2=rng.uniform(1100e-9, 1250e-9, SHAPE),
    )


def _setpoints(rng: np.random.Generator, ff: Feedforward, step: int) -> np.ndarray:
    """Set points in reach, beyond it, at its edge, negative and (every third step) NaN."""
    assert ff._laws is not None
    z = rng.uniform(0.0, 1.2, SHAPE) * ff._laws.z_sat * 0.6
    z.flat[:3] = -1e-9
    z.flat[3:6] = 2.0 * ff._laws.z_sat.flat[3:6]  # beyond any reach
    if step % 3 == 2:
        z.flat[7] = np.nan
    return z


def test_fused_is_default_and_env_forces_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(KERNELS_ENV, raising=False)
    assert default_backend() is (Backend.FUSED if fused_available() else Backend.NUMPY)
    monkeypatch.setenv(KERNELS_ENV, "numpy")
    assert default_backend() is Backend.NUMPY
    config = FeedforwardConfig(shape=SHAPE, mode=Mode.OBSERVER)
    assert Feedforward(config).backend is Backend.NUMPY
    monkeypatch.setenv(KERNELS_ENV, "gpu")
    with pytest.raises(KernelBackendError, match="expected one of auto, numpy, fused"):
        default_backend()


def test_numba_is_installed() -> None:
    assert fused_available()  # a pinned dependency: the fused path is the one that runs


@pytest.mark.parametrize(("mode", "gains"), CASES)
def test_fused_equals_numpy_over_temperatures_and_set_points(
    mode: Mode, gains: ObserverGains
) -> None:
    rng = np.random.default_rng(7)
    config = FeedforwardConfig(shape=SHAPE, params=_params(rng), mode=mode, observer=gains)
    cores = {b: Feedforward(config, backend=b) for b in Backend}
    saw = set()
    for step, T0 in enumerate(np.repeat(TEMPERATURES, 3)):
        T = T0 + rng.uniform(-1.0, 1.0, SHAPE)
        t = 0.01 * step
        for core in cores.values():
            assert core.update_temperature(T, t) is None
        z = _setpoints(rng, cores[Backend.NUMPY], step)
        numpy_result = cores[Backend.NUMPY].command(z, t)
        fused_result = cores[Backend.FUSED].command(z, t)
        np.testing.assert_array_equal(fused_result.status, numpy_result.status)
        np.testing.assert_allclose(fused_result.voltage, numpy_result.voltage, rtol=1e-12,
                                   atol=0.0)
        if numpy_result.model_error is not None:
            assert fused_result.model_error is not None
            np.testing.assert_allclose(fused_result.model_error, numpy_result.model_error,
                                       rtol=1e-12, atol=1e-24)
        for result in (numpy_result, fused_result):  # counted or taken, the largest code
            assert result.worst == int(result.status.max())
        saw.update(np.unique(numpy_result.status).tolist())
        assert np.all(np.isfinite(fused_result.voltage))
        assert fused_result.voltage.min() >= 0.0
        assert fused_result.voltage.max() <= DEFAULT_V_LIMIT
    assert {CODE_OK, CODE_CLIPPED_HIGH} <= saw  # the saturation branch was exercised


@pytest.mark.parametrize("kp", [0.0, 0.25])
def test_observer_command_backends_agree_on_saturating_voltages(kp: float) -> None:
    rng = np.random.default_rng(3)
    shape = (64,)
    q = rng.uniform(0.5e-3, 3e-2, shape)
    n = rng.uniform(1e-10, 2e-9, shape)
    laws = LawsAtTemperature(q=q, n=n, inv_zsat=q * q / n, status=np.zeros(shape, np.int8))
    z = laws.z_sat * rng.uniform(-0.1, 1.2, shape)  # some negative, some beyond saturation
    integral = rng.uniform(-10.0, 400.0, shape)  # some to be clipped
    out = {
        b: observer_command(integral, laws, z, v_limit=350.0, kp=kp, ki=1.0 - kp,
                            iterations=6, backend=b)
        for b in Backend
    }
    fused, numpy_out = out[Backend.FUSED], out[Backend.NUMPY]
    for name in ("voltage", "integral", "model_error", "tanh_of_voltage"):
        np.testing.assert_allclose(getattr(fused, name), getattr(numpy_out, name), rtol=1e-12,
                                   atol=1e-24, err_msg=name)
    assert (fused.voltage is fused.integral) == (kp == 0.0)
    assert np.any(numpy_out.voltage == 350.0)
    np.testing.assert_array_equal(numpy_out.tanh_of_voltage, np.tanh(q * numpy_out.voltage))
    assert np.all(numpy_out.integral >= 0.0)


@pytest.mark.parametrize("backend", list(Backend))
def test_reused_tanh_gives_the_numbers_of_a_fresh_start(backend: Backend) -> None:
    rng = np.random.default_rng(11)
    shape = (8, 8)
    q = rng.uniform(0.5e-3, 3e-2, shape)
    n = rng.uniform(1e-10, 2e-9, shape)
    laws = LawsAtTemperature(q=q, n=n, inv_zsat=q * q / n, status=np.zeros(shape, np.int8))
    run = partial(observer_command, laws=laws, v_limit=350.0, kp=0.0, ki=1.0, iterations=3,
                  backend=backend)
    first = run(np.zeros(shape), z=0.5 * laws.z_sat)
    z = laws.z_sat * rng.uniform(0.0, 0.9, shape)
    fresh = run(first.integral, z=z)
    reused = run(first.integral, z=z, tanh_of_integral=first.tanh_of_voltage)
    for name in ("voltage", "integral", "model_error", "tanh_of_voltage"):
        np.testing.assert_array_equal(getattr(reused, name), getattr(fresh, name), err_msg=name)
    wrong = run(first.integral, z=z, tanh_of_integral=np.zeros(shape))
    assert not np.array_equal(wrong.voltage, fresh.voltage)  # the given tanh is really used


def _observer_laws(seed: int, shape: tuple[int, ...]) -> LawsAtTemperature:
    rng = np.random.default_rng(seed)
    q = rng.uniform(0.5e-3, 3e-2, shape)
    n = rng.uniform(1e-10, 2e-9, shape)
    return LawsAtTemperature(q=q, n=n, inv_zsat=q * q / n, status=np.zeros(shape, np.int8))


def _smooth_setpoints(laws: LawsAtTemperature, steps: int) -> list[np.ndarray]:
    """A 10 Hz sine over most of each actuator's reach at 2 kHz, phases per actuator."""
    phase = np.random.default_rng(5).uniform(0.0, 2.0 * np.pi, laws.q.shape)
    return [laws.z_sat * (0.3 + 0.25 * np.sin(2.0 * np.pi * 10.0 * k / 2000.0 + phase))
            for k in range(steps)]


def _reference_loop(
    integral: np.ndarray, laws: LawsAtTemperature, z: np.ndarray, kp: float, ki: float,
    updates: int,
) -> tuple[np.ndarray, np.ndarray]:
    """observer_command's docstring, update by update: (integral, voltage)."""
    target = np.sqrt(np.maximum(z, 0.0))
    integral = np.clip(integral, 0.0, 350.0)
    voltage = integral
    for _ in range(updates):
        t = np.tanh(laws.q * voltage)
        gain = np.maximum(laws.sqrt_n * (1.0 - t * t), 1e-6 * laws.sqrt_n)
        e = (target - laws.sqrt_z_sat * t) / gain
        integral = np.clip(integral + ki * e, 0.0, 350.0)
        voltage = integral if kp == 0.0 else np.clip(integral + kp * e, 0.0, 350.0)
    return integral, voltage


@pytest.mark.parametrize("backend", list(Backend))
@pytest.mark.parametrize("kp", [0.0, 0.25])
def test_zero_tolerance_runs_every_update(backend: Backend, kp: float) -> None:
    laws = _observer_laws(12, (6, 7))
    z = laws.z_sat * np.random.default_rng(2).uniform(0.0, 0.9, laws.q.shape)
    start = np.random.default_rng(3).uniform(-5.0, 360.0, laws.q.shape)
    out = observer_command(start, laws, z, v_limit=350.0, kp=kp, ki=1.0 - kp, iterations=5,
                           tolerance=0.0, backend=backend)
    assert out.updates == 5
    integral, voltage = _reference_loop(start, laws, z, kp, 1.0 - kp, 5)
    np.testing.assert_allclose(out.integral, integral, rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(out.voltage, voltage, rtol=1e-13, atol=1e-12)
    np.testing.assert_array_equal(out.tanh_of_voltage, np.tanh(laws.q * out.voltage))


@pytest.mark.parametrize("backend", list(Backend))
def test_the_loop_stops_when_the_next_update_would_move_nothing_worth_it(
    backend: Backend,
) -> None:
    laws = _observer_laws(13, (9, 9))
    tolerance = 1e-4
    run = partial(observer_command, laws=laws, v_limit=350.0, kp=0.0, ki=1.0, iterations=6,
                  backend=backend)
    integral, tanh, counts = np.zeros(laws.q.shape), None, []
    for z in _smooth_setpoints(laws, 40):
        out = run(integral, z=z, tolerance=tolerance, tanh_of_integral=tanh)
        counts.append(out.updates)
        # exactly the first `updates` updates of a loop that does not stop early
        same = run(integral, z=z, tolerance=0.0, iterations=max(out.updates, 1),
                   tanh_of_integral=tanh)
        if out.updates:
            np.testing.assert_array_equal(out.integral, same.integral)
        else:
            np.testing.assert_array_equal(out.integral, np.clip(integral, 0.0, 350.0))
        if out.updates < 6:  # stopped early: the next update moves nothing above tolerance
            nxt = run(out.integral, z=z, tolerance=0.0, iterations=1)
            assert np.max(np.abs(nxt.integral - out.integral)) <= tolerance
        np.testing.assert_array_equal(out.tanh_of_voltage, np.tanh(laws.q * out.voltage))
        integral, tanh = out.integral, out.tanh_of_voltage
    assert max(counts[1:]) < 6 and min(counts[1:]) >= 1  # it converged early, never idle
    held = run(integral, z=z, tolerance=tolerance, tanh_of_integral=tanh)
    assert held.updates == 0  # the same set point again: nothing to do
    np.testing.assert_array_equal(held.voltage, integral)


def test_backends_stop_at_the_same_update_with_nan_and_saturated_set_points() -> None:
    laws = _observer_laws(14, (10, 10))
    outs: dict[Backend, list[tuple[int, np.ndarray, np.ndarray]]] = {}
    for backend in Backend:
        integral, tanh, seen = np.zeros(laws.q.shape), None, []
        for k, smooth in enumerate(_smooth_setpoints(laws, 30)):
            z = smooth.copy()
            z.flat[:4] = [np.nan, -1e-9, 3.0 * laws.z_sat.flat[2], 0.0]
            if k % 4 == 3:
                z.flat[10] = np.nan
            out = observer_command(integral, laws, z, v_limit=350.0, kp=0.0, ki=1.0,
                                   iterations=6, tolerance=1e-4, backend=backend,
                                   tanh_of_integral=tanh)
            seen.append((out.updates, out.voltage.copy(), out.model_error.copy()))
            integral, tanh = np.nan_to_num(out.integral), None
        outs[backend] = seen
    for (n_f, v_f, e_f), (n_n, v_n, e_n) in zip(outs[Backend.FUSED], outs[Backend.NUMPY],
                                                strict=True):
        assert n_f == n_n
        np.testing.assert_array_equal(v_f, v_n)
        np.testing.assert_array_equal(e_f, e_n)
    assert {n for n, _, _ in outs[Backend.NUMPY][1:]} - {6}  # early stops despite NaN


@pytest.mark.parametrize("T0", TEMPERATURES)
def test_reach_status_equals_the_inverse_status(T0: float) -> None:
    rng = np.random.default_rng(int(T0))
    ff = Feedforward(FeedforwardConfig(shape=SHAPE, params=_params(rng)))
    ff.update_temperature(T0 + rng.uniform(-1.0, 1.0, SHAPE), 0.0)
    laws = ff._laws
    assert laws is not None
    t = np.tanh(laws.q * DEFAULT_V_LIMIT)
    reach = t * t * laws.z_sat
    cases = [
        reach * rng.uniform(0.0, 0.9, SHAPE),  # all in reach
        reach * rng.uniform(0.5, 1.5, SHAPE),  # some beyond
        reach * (1.0 + rng.choice([-1.0, 1.0], SHAPE) * rng.uniform(0, 3, SHAPE) * REACH_MARGIN),
        reach * np.where(rng.random(SHAPE) < 0.5, 0.5, 2.0),
        reach * rng.uniform(-0.5, 1.5, SHAPE),  # negative ones
    ]
    for z in cases:
        expected = laws.hyperbolic_inverse(z, DEFAULT_V_LIMIT).status
        np.testing.assert_array_equal(ff._reach_status(laws, z), expected)


@pytest.mark.parametrize("T0", [42.0, 46.0, 50.0])
def test_fused_linearized_is_the_numpy_path_bit_for_bit(T0: float) -> None:
    rng = np.random.default_rng(int(T0))
    config = FeedforwardConfig(shape=SHAPE, params=_params(rng), mode=Mode.LINEARIZED_DMAX)
    cores = {b: Feedforward(config, backend=b) for b in Backend}
    T = T0 + rng.uniform(-1.0, 1.0, SHAPE)
    for core in cores.values():
        core.update_temperature(T, 0.0)
    laws = cores[Backend.FUSED]._laws
    assert laws is not None and not laws.flagged
    _, below, beyond = cores[Backend.FUSED]._reach_bounds(laws)
    # clearly in reach (some driven past v_limit by the linearisation), and beyond reach
    z = np.where(rng.random(SHAPE) < 0.7, below * rng.uniform(0.0, 0.999, SHAPE), 1.5 * beyond)
    z.flat[0] = 0.0
    fused = fused_linearized(laws, z, below, beyond, DEFAULT_V_LIMIT)
    assert fused is not None
    numpy_result = cores[Backend.NUMPY].command(z, 0.0)
    fused_result = cores[Backend.FUSED].command(z, 0.0)
    for result, error in ((fused[0], fused[1]), (fused_result, fused_result.model_error)):
        np.testing.assert_array_equal(result.voltage, numpy_result.voltage)
        np.testing.assert_array_equal(result.status, numpy_result.status)
        assert error is not None and numpy_result.model_error is not None
        np.testing.assert_array_equal(error, numpy_result.model_error)
    assert {CODE_OK, CODE_CLIPPED_HIGH} <= set(np.unique(fused[0].status).tolist())
    for bad in (0.5 * (below.flat[3] + beyond.flat[3]), -1e-9, np.nan):
        unclear = z.copy()
        unclear.flat[3] = bad
        assert fused_linearized(laws, unclear, below, beyond, DEFAULT_V_LIMIT) is None
        np.testing.assert_array_equal(cores[Backend.FUSED].command(unclear, 0.0).voltage,
                                      cores[Backend.NUMPY].command(unclear, 0.0).voltage)


def test_fused_reach_status_takes_clear_set_points_and_leaves_unclear_ones() -> None:
    rng = np.random.default_rng(5)
    ff = Feedforward(FeedforwardConfig(shape=SHAPE, params=_params(rng)), backend=Backend.FUSED)
    ff.update_temperature(np.full(SHAPE, 40.0), 0.0)
    laws = ff._laws
    assert laws is not None
    _, below, beyond = ff._reach_bounds(laws)
    clear = np.where(rng.random(SHAPE) < 0.5, 0.5 * below, 2.0 * beyond)
    voltage = rng.uniform(0.0, 400.0, SHAPE)  # some over the limit
    limited = np.minimum(voltage, DEFAULT_V_LIMIT)
    status = fused_reach_status(clear, voltage, below, beyond, DEFAULT_V_LIMIT)
    assert status is not None
    expected = laws.hyperbolic_inverse(clear, DEFAULT_V_LIMIT).status
    expected[limited == DEFAULT_V_LIMIT] = CODE_CLIPPED_HIGH
    np.testing.assert_array_equal(status, expected)
    np.testing.assert_array_equal(voltage, limited)
    for bad in (0.5 * (below + beyond), -1e-9, np.nan):
        z = clear.copy()
        z.flat[4] = bad if np.isscalar(bad) else bad.flat[4]  # type: ignore[union-attr]
        before = rng.uniform(0.0, 400.0, SHAPE)
        voltage = before.copy()
        assert fused_reach_status(z, voltage, below, beyond, DEFAULT_V_LIMIT) is None
        np.testing.assert_array_equal(voltage, before)  # untouched: the caller inverts


@pytest.mark.parametrize("T0", [42.0, 50.0])  # +- 1 degC: inside the laws' range
def test_fused_hyperbolic_inverse_is_the_numpy_inverse_bit_for_bit(T0: float) -> None:
    rng = np.random.default_rng(11)
    ff = Feedforward(FeedforwardConfig(shape=SHAPE, params=_params(rng)), backend=Backend.FUSED)
    ff.update_temperature(T0 + rng.uniform(-1.0, 1.0, SHAPE), 0.0)
    laws = ff._laws
    assert laws is not None and not laws.flagged
    # in reach, beyond what v_limit reaches (clipped there) and just below saturation
    z = rng.uniform(0.0, 0.99, SHAPE) * laws.z_sat
    z.flat[:4] = laws.z_sat.flat[:4] * (1.0 - 1e-11)
    z.flat[4] = 0.0
    for given in (z, np.asfortranarray(z), np.frombuffer(z.tobytes()).reshape(SHAPE)):
        fused = fused_hyperbolic_inverse(laws, given, DEFAULT_V_LIMIT)
        expected = laws.hyperbolic_inverse(given, DEFAULT_V_LIMIT)
        assert fused is not None
        np.testing.assert_array_equal(fused.voltage, expected.voltage)
        np.testing.assert_array_equal(fused.status, expected.status)
        assert fused.voltage.shape == SHAPE and fused.status.dtype == np.int8
    assert np.any(expected.status == CODE_CLIPPED_HIGH) and np.any(expected.status == CODE_OK)


@pytest.mark.parametrize("bad", [-1e-12, np.nan, np.inf, 1.0])
def test_fused_hyperbolic_inverse_leaves_unclean_set_points_to_numpy(bad: float) -> None:
    rng = np.random.default_rng(12)
    ff = Feedforward(FeedforwardConfig(shape=SHAPE, params=_params(rng)), backend=Backend.FUSED)
    ff.update_temperature(np.full(SHAPE, 46.0), 0.0)
    laws = ff._laws
    assert laws is not None
    z = rng.uniform(0.0, 0.5, SHAPE) * laws.z_sat
    z.flat[-1] = bad * laws.z_sat.flat[-1] if bad == 1.0 else bad  # 1.0: at saturation
    assert fused_hyperbolic_inverse(laws, z, DEFAULT_V_LIMIT) is None
    # and the feedforward gives the numpy path's command for it
    numpy_ff = Feedforward(ff.config, backend=Backend.NUMPY)
    numpy_ff.update_temperature(np.full(SHAPE, 46.0), 0.0)
    fused_result, numpy_result = ff.command(z, 0.0), numpy_ff.command(z, 0.0)
    np.testing.assert_array_equal(fused_result.voltage, numpy_result.voltage)
    np.testing.assert_array_equal(fused_result.status, numpy_result.status)


def test_fused_hyperbolic_inverse_refuses_set_points_above_the_callers_ceiling() -> None:
    # a model whose saturation (10 m) lies beyond the ceiling: only the ceiling refuses
    ones = np.ones(SHAPE)
    laws = LawsAtTemperature(q=ones * 0.01, n=ones * 1e-5, inv_zsat=ones * 0.1,
                             status=np.zeros(SHAPE, np.int8), flagged=False)
    z = np.full(SHAPE, 0.5)
    z.flat[5] = 1.5
    assert fused_hyperbolic_inverse(laws, z, DEFAULT_V_LIMIT, ceiling=1.0) is None
    taken = fused_hyperbolic_inverse(laws, z, DEFAULT_V_LIMIT)
    assert taken is not None
    expected = laws.hyperbolic_inverse(z, DEFAULT_V_LIMIT)
    np.testing.assert_array_equal(taken.voltage, expected.voltage)
    assert taken.worst == int(taken.status.max())


@pytest.mark.parametrize(("mode", "loaders"), [
    (Mode.INVERSE_HYPERBOLIC, [kernels._fused_hyperbolic]),
    (Mode.UNCOMPENSATED, [kernels._fused_hyperbolic]),
    (Mode.LINEARIZED_DMAX, [kernels._fused_linearized]),
    (Mode.OBSERVER, [kernels._fused_observer, kernels._fused_reach_limit]),
])  # fmt: skip
def test_a_feedforward_loads_its_modes_kernels_when_built(mode: Mode, loaders: list) -> None:
    for loader in loaders:
        loader.cache_clear()
    Feedforward(FeedforwardConfig(shape=SHAPE, mode=mode), backend=Backend.FUSED)
    # loaded before any set point: the first one is not held up by numba (0.1-1.7 s)
    assert all(loader.cache_info().currsize == 1 for loader in loaders)


def test_default_mode_backends_agree_on_a_clean_stream() -> None:
    rng = np.random.default_rng(13)
    config = FeedforwardConfig(shape=SHAPE, params=_params(rng))
    assert config.mode is Mode.INVERSE_HYPERBOLIC
    cores = {b: Feedforward(config, backend=b) for b in Backend}
    for step in range(6):
        T = 46.0 + rng.uniform(-3.0, 3.0, SHAPE)
        for core in cores.values():
            core.update_temperature(T, 0.01 * step)
        laws = cores[Backend.FUSED]._laws
        assert laws is not None
        z = rng.uniform(0.0, 0.95, SHAPE) * laws.z_sat
        fused, numpy_ = (cores[b].command(z, 0.01 * step) for b in (Backend.FUSED, Backend.NUMPY))
        np.testing.assert_array_equal(fused.voltage, numpy_.voltage)
        np.testing.assert_array_equal(fused.status, numpy_.status)
        assert not fused.held and fused.voltage.max() <= DEFAULT_V_LIMIT
