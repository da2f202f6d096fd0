"""Property-based tests (hypothesis) of the cores: any input, finite and in limits, or the
documented error.

Conversions (es_msgs_py.arrays), the model library's inverses, the feedforward core in every
mode (with every compensation effect switched on), the plant's command check and the thermal
estimators are fed arbitrary shapes and values, including NaN, +-inf, huge, negative and
out-of-range ones (bags: test_bad_bags.py).
"""

from __future__ import annotations

import contextlib
import copy
from typing import TYPE_CHECKING

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from es_feedforward.compensation import CompensationParams
from es_feedforward.feedforward import Feedforward, FeedforwardConfig, Mode
from es_msgs_py.arrays import (
    LayoutError,
    grid_to_msg,
    msg_to_grid,
    msg_to_sensors,
    sensors_to_msg,
)
from es_physics.laws import (
    DEFAULT_V_LIMIT,
    Status,
    hyperbolic_inverse,
    quadratic_inverse,
)
from es_physics.params import ActuatorParams
from es_sim_plant.plant import Plant
from es_sim_plant.scenario import load_scenario
from es_thermal.estimator import EstimatorConfig, TemperatureEstimator
from es_thermal.interpolation import actuator_positions

if TYPE_CHECKING:
    from .conftest import FaultCases

EXAMPLES = 60
# No shrinking: a failure shows its first example at once instead of minutes later.
PROPERTY = settings(
    max_examples=EXAMPLES,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
    phases=[Phase.explicit, Phase.reuse, Phase.generate],
)

#: Any float64, including NaN, +-inf, huge, tiny and negative values.
any_float = st.floats(allow_nan=True, allow_infinity=True, width=64)
#: Physically plausible floats mixed with hostile ones.
temperature_like = st.one_of(st.floats(-50.0, 150.0), any_float)
setpoint_like = st.one_of(st.floats(0.0, 3e-7), any_float)

small_shapes = hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=5)
grid_shapes = st.tuples(st.integers(1, 6), st.integers(1, 6))


def _in_limits(voltage: np.ndarray, v_limit: float) -> bool:
    return bool(np.all(np.isfinite(voltage)) and np.all((voltage >= 0.0) & (voltage <= v_limit)))


# --- conversions ---------------------------------------------------------------------------


@PROPERTY
@given(hnp.arrays(np.float64, hnp.array_shapes(min_dims=2, max_dims=2, min_side=0, max_side=9),
                  elements=any_float))
def test_grid_round_trip_keeps_every_value(grid: np.ndarray) -> None:
    back = msg_to_grid(grid_to_msg(grid), (grid.shape[0], grid.shape[1]))
    assert back.shape == grid.shape
    np.testing.assert_array_equal(back, grid)  # NaN == NaN here


@PROPERTY
@given(hnp.arrays(np.float64, st.integers(0, 40), elements=any_float))
def test_sensor_round_trip_keeps_every_value(values: np.ndarray) -> None:
    np.testing.assert_array_equal(msg_to_sensors(sensors_to_msg(values), values.size), values)


dims = st.lists(
    st.builds(
        lambda label, size, stride: MultiArrayDimension(label=label, size=size, stride=stride),
        st.sampled_from(["row", "col", "sensor", "", "x"]),
        st.integers(0, 12),
        st.integers(0, 150),
    ),
    max_size=3,
)


@PROPERTY
@given(dims, st.integers(0, 3), st.lists(any_float, max_size=150),
       st.one_of(st.none(), grid_shapes), st.one_of(st.none(), st.integers(0, 12)))
def test_any_message_layout_gives_the_configured_array_or_layout_error(
    layout: list[MultiArrayDimension],
    offset: int,
    data: list[float],
    shape: tuple[int, int] | None,
    count: int | None,
) -> None:
    msg = Float64MultiArray()
    msg.layout.dim = layout
    msg.layout.data_offset = offset
    msg.data = data
    try:
        grid = msg_to_grid(msg, shape)
    except LayoutError:
        pass
    else:
        assert grid.ndim == 2 and grid.size == len(data)
        assert shape is None or grid.shape == shape
    try:
        sensors = msg_to_sensors(msg, count)
    except LayoutError:
        pass
    else:
        assert sensors.shape == (len(data),)
        assert count is None or sensors.size == count


def test_conversions_reject_hostile_messages(fault_cases: FaultCases) -> None:
    """Named cases of the property above, so that they show in the fault tally."""
    good = grid_to_msg(np.ones((2, 3)))

    def variant(**changes: object) -> Float64MultiArray:
        msg = Float64MultiArray()
        msg.layout.dim = [MultiArrayDimension(label=d.label, size=d.size, stride=d.stride)
                          for d in good.layout.dim]
        msg.data = list(good.data)
        for key, value in changes.items():
            if key == "data":
                msg.data = value
            elif key == "offset":
                msg.layout.data_offset = value
            elif key == "dims":
                msg.layout.dim = value
        return msg

    cases = {
        "empty message": Float64MultiArray(),
        "too few values": variant(data=[1.0] * 5),
        "too many values": variant(data=[1.0] * 7),
        "transposed layout": grid_to_msg(np.ones((3, 2))),
        "sensor layout on a grid topic": sensors_to_msg(np.ones(6)),
        "non-zero data_offset": variant(offset=1),
        "wrong labels": variant(dims=[MultiArrayDimension(label="col", size=2, stride=6),
                                      MultiArrayDimension(label="row", size=3, stride=3)]),
        "wrong strides": variant(dims=[MultiArrayDimension(label="row", size=2, stride=3),
                                       MultiArrayDimension(label="col", size=3, stride=3)]),
    }
    for name, msg in cases.items():
        try:
            msg_to_grid(msg, (2, 3))
            held = False
        except LayoutError:
            held = True
        fault_cases.expect("conversions", name, held, "LayoutError expected")
    fault_cases.assert_held()


# --- models --------------------------------------------------------------------------------


@PROPERTY
@given(hnp.arrays(np.float64, small_shapes, elements=setpoint_like),
       hnp.arrays(np.float64, small_shapes, elements=temperature_like),
       st.floats(1.0, 1000.0))
def test_every_inverse_is_finite_and_within_limits(
    z: np.ndarray, T: np.ndarray, v_limit: float
) -> None:
    params = ActuatorParams()
    try:
        shape = np.broadcast_shapes(z.shape, T.shape)
    except ValueError:
        with pytest.raises(ValueError):
            hyperbolic_inverse(z, T, params, v_limit)
        return
    for inverse in (hyperbolic_inverse, quadratic_inverse):
        result = inverse(z, T, params, v_limit)
        assert result.voltage.shape == shape
        assert _in_limits(result.voltage, v_limit)
        assert set(np.unique(result.status)) <= {int(s) for s in Status}
        # non-finite input: INVALID and 0 V
        bad = ~np.isfinite(np.broadcast_to(z, shape)) | ~np.isfinite(np.broadcast_to(T, shape))
        assert np.all(result.status[bad] == Status.INVALID)
        assert np.all(result.voltage[bad] == 0.0)


@st.composite
def configurations(draw: st.DrawFn) -> FeedforwardConfig:
    """A feedforward configuration of any mode with every compensation effect possibly on."""
    shape = draw(grid_shapes)
    compensation = CompensationParams(
        temperature_lead_s=draw(st.sampled_from([0.0, 0.5, 30.0])),
        delay_s=draw(st.sampled_from([0.0, 0.002, 0.5])),
        hysteresis_weight=draw(st.sampled_from([0.0, 0.3, 0.9])),
        hysteresis_threshold_v=draw(st.sampled_from([0.0, 20.0, 1000.0])),
        coupling=draw(st.sampled_from([0.0, -0.12, 0.05, 0.12])),
        thermal_expansion=draw(st.sampled_from([0.0, 1e-8, -1e-8])),
        drift_fraction=draw(st.sampled_from([0.0, 0.5])),
        drift_tau_s=draw(st.sampled_from([1e-3, 100.0])),
    )
    return FeedforwardConfig(
        shape=shape,
        mode=draw(st.sampled_from(list(Mode))),
        v_limit=draw(st.sampled_from([1.0, 150.0, DEFAULT_V_LIMIT, 1000.0])),
        compensation=compensation,
    )


@PROPERTY
@given(configurations(), st.data())
def test_feedforward_core_any_mode_any_input_stays_finite_and_in_limits(
    config: FeedforwardConfig, data: st.DataObject
) -> None:
    core = Feedforward(config)
    t = 0.0
    for _ in range(data.draw(st.integers(1, 6))):
        t += data.draw(st.sampled_from([0.0, 0.001, 0.01, 5.0, -1.0]))  # also time going back
        grid = hnp.arrays(np.float64, config.shape, elements=temperature_like)
        if data.draw(st.booleans()):
            problem = core.update_temperature(data.draw(grid), t)
            assert problem is None or isinstance(problem, str)
        z = data.draw(hnp.arrays(np.float64, config.shape, elements=setpoint_like))
        result = core.command(z, t)
        assert result.voltage.shape == config.shape
        assert _in_limits(result.voltage, config.v_limit)
        assert result.held == (result.problem is not None)
        if result.model_error is not None:
            assert np.all(np.isfinite(result.model_error))


@PROPERTY
@given(st.sampled_from(list(Mode)), grid_shapes, small_shapes)
def test_feedforward_core_wrong_shapes_raise_value_error(
    mode: Mode, shape: tuple[int, int], wrong: tuple[int, ...]
) -> None:
    if wrong == shape:
        return
    core = Feedforward(FeedforwardConfig(shape=shape, mode=mode))
    with pytest.raises(ValueError, match="expected"):
        core.update_temperature(np.full(wrong, 45.0), 0.0)
    with pytest.raises(ValueError, match="expected"):
        core.command(np.zeros(wrong), 0.0)


@PROPERTY
@given(grid_shapes, st.sampled_from(["m2", "k2", "L", "Tm"]),
       st.sampled_from([np.nan, np.inf, -1.0, 0.0, 1e300, -1e300]))
def test_unusable_law_parameters_are_rejected_at_configuration(
    shape: tuple[int, int], name: str, value: float
) -> None:
    params = ActuatorParams(**{name: np.full(shape, value)})
    config = FeedforwardConfig(shape=shape, params=params)
    reason = config.reason_to_reject()
    if reason is None:  # e.g. a huge Tm only shifts the laws: then outputs must be safe
        result = Feedforward(config).command(np.full(shape, 1e-7), 0.0)
        assert _in_limits(result.voltage, config.v_limit)
    else:
        with pytest.raises(ValueError):
            Feedforward(config)


# --- plant command check ---------------------------------------------------------------------


@PROPERTY
@given(hnp.arrays(np.float64, small_shapes, elements=st.one_of(st.floats(-350, 350), any_float)))
def test_plant_accepts_only_finite_in_limit_commands_of_its_shape(command: np.ndarray) -> None:
    plant = _plant_2x2()
    reason = plant.check_command(command)
    safe = (command.shape == plant.shape and bool(np.all(np.isfinite(command)))
            and bool(np.all(np.abs(command) <= plant.v_limit)))
    assert (reason is None) == safe
    if command.shape != plant.shape or not np.all(np.isfinite(command)):
        with pytest.raises(ValueError):
            plant.step(command)


_PLANTS: dict[str, Plant] = {}


def _plant_2x2() -> Plant:
    if "plant" not in _PLANTS:
        _PLANTS["plant"] = Plant(load_scenario("dm_exposure").with_overrides(rows=2, cols=2))
    return _PLANTS["plant"]


# --- estimators ----------------------------------------------------------------------------


_ESTIMATORS: dict[str, TemperatureEstimator] = {}


def _estimator(kind: str) -> TemperatureEstimator:
    """A fresh estimator (a copy of one built per kind: construction solves a Riccati)."""
    if kind not in _ESTIMATORS:
        config = EstimatorConfig(rows=3, cols=3, positions=actuator_positions(3, 3), kind=kind)
        _ESTIMATORS[kind] = TemperatureEstimator(config)
    return copy.deepcopy(_ESTIMATORS[kind])


@PROPERTY
@given(st.sampled_from(["model", "lowpass"]), st.data())
def test_estimators_give_finite_estimate_or_no_estimate(kind: str, data: st.DataObject) -> None:
    estimator = _estimator(kind)
    t = data.draw(st.floats(0.0, 1e6))
    for _ in range(data.draw(st.integers(1, 8))):
        t += data.draw(st.sampled_from([0.1, 0.1, 0.0, 0.3, 500.0, -2.0]))
        if data.draw(st.booleans()):
            # plausible loads and non-finite ones; hostile magnitudes: the test below
            heat = data.draw(hnp.arrays(np.float64, (3, 3), elements=st.one_of(
                st.floats(0.0, 1.0), st.sampled_from([np.nan, np.inf, -np.inf]))))
            try:
                estimator.set_heat_load(heat)
            except ValueError:
                assert not np.all(np.isfinite(heat))
        readings = data.draw(hnp.arrays(np.float64, 9, elements=temperature_like))
        estimate = estimator.update(t, readings)
        valid = estimate.health.valid
        assert not np.any(valid & ~np.isfinite(readings))  # a non-finite reading is never used
        if estimate.temperatures is None:
            assert not np.any(valid)  # the documented no-estimate state: no valid sensor
        else:
            assert estimate.temperatures.shape == (3, 3)
            assert np.all(np.isfinite(estimate.temperatures))


@PROPERTY
@given(st.sampled_from(["model", "lowpass"]),
       hnp.arrays(np.float64, st.integers(0, 20), elements=temperature_like))
def test_estimators_reject_readings_of_the_wrong_length(kind: str, readings: np.ndarray) -> None:
    if readings.size == 9:
        return
    with pytest.raises(ValueError):
        _estimator(kind).update(1e7, readings)


@pytest.mark.parametrize("kind", ["model", "lowpass"])
def test_estimators_survive_hostile_heat_loads(kind: str, fault_cases: FaultCases) -> None:
    """A heat load of absurd magnitude is rejected, or the estimate stays finite and recovers."""
    rng = np.random.default_rng(3)
    for load in (1e6, 1e12, 1e300, -1e6):
        estimator = _estimator(kind)
        t = 0.0
        try:
            for step in range(40):
                t += 0.1
                heat = np.full((3, 3), load if 3 <= step < 8 else 0.0)
                with contextlib.suppress(ValueError):  # rejected: the documented error
                    estimator.set_heat_load(heat)
                estimate = estimator.update(t, 45.0 + 0.01 * rng.standard_normal(9))
            last = estimate.temperatures
            held = last is None or bool(np.all(np.isfinite(last)) and np.all(np.abs(last) < 200))
            detail = "estimate after the load returned to 0: " + (
                "none" if last is None else f"{float(np.max(np.abs(last))):.4g} degC")
        except Exception as err:  # any exception is the failure being counted
            held, detail = False, f"{type(err).__name__}: {err}"
        fault_cases.expect(f"thermal estimator ({kind})", f"heat load {load:g} W", held, detail)
    fault_cases.assert_held()
