"""The thermal node's declared parameters and the estimator configuration they give (pure).

:data:`SPECS` are what ``ros2 param describe /thermal NAME`` and ``thermal_node --help`` show
(the self-sensing ``resonance.*`` ones are :mod:`es_thermal.resonance_params`'s);
:func:`config_from_parameters` maps their values to an
:class:`~es_thermal.estimator.EstimatorConfig`. Every time-like parameter is physical;
``time_scale`` shortens them all as the simulator's scenarios do.
"""

from __future__ import annotations

import array
from collections.abc import Callable, Mapping
from dataclasses import fields

import numpy as np

from es_node_runtime.param_spec import ParameterSpec, ParameterValues
from es_thermal.estimator import ESTIMATORS, EstimatorConfig
from es_thermal.faults import FaultConfig
from es_thermal.interpolation import block_centre_positions, sensor_positions
from es_thermal.kalman import KalmanTuning
from es_thermal.lowpass import DEFAULT_CUTOFF_HZ, DEFAULT_ORDER
from es_thermal.network import NetworkParams

__all__ = ["SPECS", "config_from_parameters", "per_sensor_value"]

#: Ranges of the per-sensor calibration parameters (one value for all or one per sensor):
#: the lag [s], the offset and its uncertainty [degC].
LAG_RANGE = (0.0, 1e4)
OFFSET_RANGE = (-100.0, 100.0)
OFFSET_SD_RANGE = (0.0, 100.0)


def _check_positions(value: object) -> str | None:
    if isinstance(value, bytes | bytearray) and not value:
        return None  # the untyped empty default
    ok = isinstance(value, list | tuple | array.array) and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value
    )
    if not ok or not isinstance(value, list | tuple | array.array):
        return "sensor_positions must be a list of numbers [r0, c0, r1, c1, ...]"
    if len(value) % 2:
        return "sensor_positions needs an even count [r0, c0, r1, c1, ...]"
    return None


def _per_sensor_check(name: str, low: float, high: float) -> Callable[[object], str | None]:
    """Return the check of a parameter that is one number or a list of one per sensor."""

    def check(value: object) -> str | None:
        items = list(value) if isinstance(value, list | tuple | array.array) else [value]
        numbers = [v for v in items if isinstance(v, int | float) and not isinstance(v, bool)]
        if len(numbers) != len(items):
            return f"{name} must be a number or a list of numbers (one per sensor)"
        if not numbers or not all(low <= v <= high for v in numbers):
            return f"{name}={value!r}: every value must lie in [{low}, {high}]"
        return None

    return check


def _per_sensor(name: str, range_: tuple[float, float], description: str) -> ParameterSpec:
    """Return the spec of a number, or a list of one per sensor, within ``range_``."""
    return ParameterSpec(
        name, 0.0, description + " One value for all sensors, or a list of one per sensor.",
        *range_, check=_per_sensor_check(name, *range_), read_only=True, dynamic_typing=True,
    )


def per_sensor_value(values: ParameterValues, name: str) -> float | list[float]:
    """Return parameter ``name``: one number for all sensors, or a list of one per sensor.

    Raises:
        KeyError: ``name`` is absent.
        es_msgs_py.errors.ParameterTypeError: neither a number nor a list of numbers.

    """
    raw = values[name]
    if isinstance(raw, int | float) and not isinstance(raw, bool):
        return values.get_float(name)
    return values.get_floats(name)


_NETWORK = NetworkParams()
_TUNING = KalmanTuning(sensor_noise=0.02)
_FAULTS = FaultConfig()

SPECS: tuple[ParameterSpec, ...] = (
    ParameterSpec(
        "estimator",
        "model",
        "Estimator: 'model' = Kalman filter on the thermal network driven by /dm/heat_load; "
        "'lowpass' = the thesis's low-pass filter (lowpass.cutoff_hz) plus spatial "
        "interpolation between sensors.",
        choices=ESTIMATORS,
        read_only=True,
    ),
    ParameterSpec("rows", 12, "Actuator grid rows.", 1, 256, read_only=True),
    ParameterSpec("cols", 12, "Actuator grid columns.", 1, 256, read_only=True),
    ParameterSpec(
        "sensor_positions",
        [],
        "Sensor (row, col) positions, flat [r0, c0, r1, c1, ...], fractional allowed; "
        "empty: see sensor_pitch.",
        check=_check_positions,
        read_only=True,
        dynamic_typing=True,  # an empty default has no array type of its own
    ),
    ParameterSpec(
        "sensor_pitch",
        1,
        "Without sensor_positions: one sensor per pitch x pitch actuators at the block "
        "centre (1: sensor i on actuator i).",
        1,
        64,
        read_only=True,
    ),
    ParameterSpec(
        "sample_rate", 10.0, "Sensor sample rate the filters are built for, Hz.", 0.01, 10000.0,
        read_only=True,
    ),
    ParameterSpec(
        "publish_rate",
        0.0,
        "0: one estimate per accepted raw message (lockstep); > 0: newest estimate at this "
        "rate, Hz.",
        0.0,
        10000.0,
        read_only=True,
    ),
    ParameterSpec(
        "diagnostics_period", 1.0, "Period of /diagnostics, wall s.", 0.01, 60.0,
        read_only=True,
    ),
    ParameterSpec(
        "ready_subscribers", 0,
        "Subscriptions /dm/temperature must have matched before 'thermal: ready' (the peers "
        "and recorder that must get the first estimate; the graph sets it).", 0, 64,
        read_only=True,
    ),
    ParameterSpec(
        "time_scale",
        1.0,
        "Multiplier of every slow time (the simulator's shortened scenarios; 1 = physical): "
        "thermal capacitances, sensor_lag_tau, model.adaptation_time; divides "
        "lowpass.cutoff_hz; model noise intensities grow by 1/sqrt(time_scale).",
        1e-4,
        1e4,
        read_only=True,
    ),
    _per_sensor(
        "sensor_lag_tau", LAG_RANGE,
        "First-order lag of the sensor behind its site, a state of the model, s.",
    ),
    _per_sensor(
        "sensor_offsets", OFFSET_RANGE,
        "What a sensor reads above its site (a calibration's), subtracted, degC.",
    ),
    _per_sensor(
        "sensor_offsets_sd", OFFSET_SD_RANGE,
        "1-sigma uncertainty of sensor_offsets, degC (reported on the estimate diagnostic).",
    ),
    ParameterSpec(
        "lowpass.cutoff_hz", DEFAULT_CUTOFF_HZ, "Low-pass cut-off, Hz.", 1e-5, 1e4,
        read_only=True,
    ),
    ParameterSpec(
        "lowpass.order", DEFAULT_ORDER, "Low-pass filter order (dimensionless).", 1, 8,
        read_only=True,
    ),
    *(
        ParameterSpec(
            f"thermal.{f.name}",
            float(getattr(_NETWORK, f.name)),
            f"Thermal network: {f.name} (capacitances J/K, conductances W/K).",
            0.0,
            1e6,
            read_only=True,
        )
        for f in fields(NetworkParams)
    ),
    ParameterSpec(
        "model.sensor_noise", _TUNING.sensor_noise, "Sensor noise the filter assumes, degC rms.",
        1e-6, 100.0, read_only=True,
    ),
    ParameterSpec(
        "model.process_noise", _TUNING.process_noise,
        "Model error per cell temperature, degC/sqrt(s).", 1e-9, 100.0, read_only=True,
    ),
    ParameterSpec(
        "model.base_drift", _TUNING.base_drift,
        "Random-walk intensity of the unmeasured base plate, degC/sqrt(s).", 1e-9, 100.0,
        read_only=True,
    ),
    ParameterSpec(
        "model.adaptation_time", _TUNING.adaptation_time,
        "Memory of the heat-gain and time-scale error estimates, s (scaled by time_scale).",
        1e-3, 1e7, read_only=True,
    ),
    ParameterSpec(
        "model.step_gate", _TUNING.step_gate,
        "Stage steps: the sensors' mean innovation, in standard deviations, beyond which a "
        "stage step is followed (0: off).", 0.0, 1e3, read_only=True,
    ),
    ParameterSpec(
        "model.step_size", _TUNING.step_size,
        "Size of a stage step the filter expects when it follows one, 1 sigma, degC.",
        1e-6, 1e3, read_only=True,
    ),
    ParameterSpec(
        "fault.valid_min", _FAULTS.valid_min, "Lowest physical reading, degC.", -273.0, 1000.0,
        read_only=True,
    ),
    ParameterSpec(
        "fault.valid_max", _FAULTS.valid_max, "Highest physical reading, degC.", -273.0, 1000.0,
        read_only=True,
    ),
    ParameterSpec(
        "fault.stuck_time", _FAULTS.stuck_time,
        "A reading unchanged (within stuck_band) this long is stuck, s of sample time.",
        1e-3, 1e7, read_only=True,
    ),
    ParameterSpec(
        "fault.stuck_band", _FAULTS.stuck_band,
        "Peak-to-peak change that still counts as unchanged, degC.", 0.0, 10.0, read_only=True,
    ),
    ParameterSpec(
        "fault.stale_timeout", _FAULTS.stale_timeout,
        "No raw message for this long (wall s) stops the estimates (ERROR).", 1e-3, 1e4,
        read_only=True,
    ),
    ParameterSpec(
        "fault.max_heat_load", _FAULTS.max_heat_load,
        "A /dm/heat_load with a cell above this is rejected (last heat load held), W per cell.",
        1e-6, 1e6, read_only=True,
    ),
    ParameterSpec(
        "fault.heat_load_tolerance", _FAULTS.heat_load_tolerance,
        "Negative heat loads down to minus this pass as rounding; lower ones are rejected, W.",
        0.0, 1e3, read_only=True,
    ),
)


def config_from_parameters(values: Mapping[str, object]) -> EstimatorConfig:
    """Build the estimator configuration from the values of :data:`SPECS` by name.

    ``sensor_lag_tau``, ``sensor_offsets`` and ``sensor_offsets_sd`` are one number for all
    sensors or a list of one per sensor (:func:`per_sensor_value`).

    Raises:
        ValueError: an inconsistent combination (positions outside the grid, cut-off above
            Nyquist, a per-sensor list of the wrong length, ...); the message says which.
        KeyError: a parameter of :data:`SPECS` is missing from ``values``.
        es_node_runtime.errors.ParameterTypeError: a value has the wrong type (a ``TypeError``).

    """
    typed = ParameterValues(values)
    num = typed.get_float
    rows, cols = typed.get_int("rows"), typed.get_int("cols")
    flat = typed.get_floats("sensor_positions")
    if not flat:
        positions = block_centre_positions(rows, cols, typed.get_int("sensor_pitch"))
    else:
        positions = sensor_positions(rows, cols, flat[0::2], flat[1::2])
    scale = num("time_scale")
    network = NetworkParams(
        **{f.name: num(f"thermal.{f.name}") for f in fields(NetworkParams)}
    ).time_scaled(scale)
    tuning = KalmanTuning(
        sensor_noise=num("model.sensor_noise"),
        process_noise=num("model.process_noise"),
        base_drift=num("model.base_drift"),
        adaptation_time=num("model.adaptation_time"),
        step_gate=num("model.step_gate"),
        step_size=num("model.step_size"),
    ).time_scaled(scale)
    faults = FaultConfig(
        valid_min=num("fault.valid_min"),
        valid_max=num("fault.valid_max"),
        stuck_time=num("fault.stuck_time"),
        stuck_band=num("fault.stuck_band"),
        stale_timeout=num("fault.stale_timeout"),
        max_heat_load=num("fault.max_heat_load"),
        heat_load_tolerance=num("fault.heat_load_tolerance"),
    )
    return EstimatorConfig(
        rows=rows,
        cols=cols,
        positions=positions,
        kind=typed.get_str("estimator"),
        sample_period=1.0 / num("sample_rate"),
        lowpass_cutoff_hz=num("lowpass.cutoff_hz") / scale,
        lowpass_order=typed.get_int("lowpass.order"),
        sensor_tau=np.asarray(per_sensor_value(typed, "sensor_lag_tau"), float) * scale,
        sensor_offsets=np.asarray(per_sensor_value(typed, "sensor_offsets"), float),
        sensor_offset_sd=np.asarray(per_sensor_value(typed, "sensor_offsets_sd"), float),
        network=network,
        tuning=tuning,
        faults=faults,
    )
