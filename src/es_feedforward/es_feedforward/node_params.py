"""The feedforward node's declared parameters: names, defaults, ranges, units and meanings.

What ``ros2 param describe /feedforward NAME`` and ``feedforward_node --help`` show; the
names are :mod:`es_feedforward.param_file`'s.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from es_feedforward.compensation import DESCRIPTIONS as COMPENSATION_DESCRIPTIONS
from es_feedforward.compensation import PREFIX as COMPENSATION_PREFIX
from es_feedforward.compensation import RANGES as COMPENSATION_RANGES
from es_feedforward.compensation import CompensationParams
from es_feedforward.feedforward import (
    DEFAULT_REFERENCE_TEMPERATURE,
    DEFAULT_TEMPERATURE_TIMEOUT,
    Mode,
    ObserverGains,
)
from es_feedforward.feedforward_config import OBSERVER_ITERATIONS_RANGE, OBSERVER_TOLERANCE_RANGE
from es_feedforward.param_file import (
    CALIBRATION_REASONS,
    CALIBRATION_VERDICT,
    LAW_FIELDS,
    LAW_PREFIX,
    OBSERVER_PREFIX,
    VERDICTS,
)
from es_node_runtime.node_main import executor_spec
from es_node_runtime.params import Check, ParameterSpec
from es_physics.laws import DEFAULT_V_LIMIT
from es_physics.params import ActuatorParams

#: What each ``mode`` does (the parameter's description lists them).
MODE_MEANINGS: Final = {
    Mode.INVERSE_HYPERBOLIC: "inverse of the hyperbolic model z(V, T) at each actuator's "
    "estimated temperature (the default)",
    Mode.INVERSE_QUADRATIC: "V = sqrt(z L / M(T)), the quadratic law's inverse (the thesis's "
    "hardware scheme)",
    Mode.LINEARIZED_DMAX: "V = V_max(T) + (z - z_sat(T)/3) / d_max(T), linearised around the "
    "steepest point, its own error reported per actuator",
    Mode.OBSERVER: "the hyperbolic model as observer and a PI loop driving its output to the "
    "set point (observer.kp, observer.ki, observer.iterations, observer.tolerance)",
    Mode.UNCOMPENSATED: "hyperbolic inverse at the fixed reference_temperature, ignoring "
    "/dm/temperature (the baseline)",
}
#: Units of the temperature-law fields ``law.<field>`` (T* = T - Tm in degC).
LAW_UNITS: Final = {
    "L": "actuator thickness, m",
    "Tm": "temperature of maximum permittivity, degC",
    "m1": "M(T*) slope, m^2/V^2 per degC",
    "m2": "M(T*) at T* = 0, m^2/V^2",
    "m3": "M(T*) curvature, m^2/V^2 per degC^2",
    "k1": "k(T*) slope, m/V per degC",
    "k2": "k(T*) at T* = 0, m/V",
    "k3": "k(T*) curvature, m/V per degC^2",
}


def _double_array_check(name: str) -> Check:
    """Return a check rejecting empty or non-finite double arrays (rclpy gives array.array)."""

    def check(value: object) -> str | None:
        if isinstance(value, str | bytes) or not hasattr(value, "__len__"):
            return f"{name} must be a double array"
        values = np.asarray(value, dtype=np.float64)
        if values.size == 0:
            return f"{name} must be a non-empty double array"
        if not np.all(np.isfinite(values)):
            return f"{name} must hold finite values"
        return None

    return check


def parameter_specs() -> list[ParameterSpec]:
    """Return every declared parameter of the node (defaults: thesis laws, effects off)."""
    law_defaults = ActuatorParams()
    compensation_defaults = CompensationParams()
    observer_defaults = ObserverGains()
    specs = [
        ParameterSpec("rows", 12, "Grid rows R (actuators).", 1, 1024, read_only=True),
        executor_spec(),
        ParameterSpec("cols", 12, "Grid columns C (actuators).", 1, 1024, read_only=True),
        ParameterSpec(
            "mode",
            Mode.INVERSE_HYPERBOLIC.value,
            "Feedforward scheme: "
            + "; ".join(f"'{m.value}': {meaning}" for m, meaning in MODE_MEANINGS.items())
            + ".",
            choices=[m.value for m in Mode],
        ),
        ParameterSpec("v_limit", DEFAULT_V_LIMIT, "Amplifier limit [V].", 1.0, 1000.0),
        ParameterSpec(
            "reference_temperature",
            DEFAULT_REFERENCE_TEMPERATURE,
            "Temperature [degC] at which 'uncompensated' evaluates the model.",
            -50.0,
            150.0,
        ),
        ParameterSpec(
            "temperature_timeout",
            DEFAULT_TEMPERATURE_TIMEOUT,
            "Age [s, ROS time] beyond which the temperature estimate is stale (0: never).",
            0.0,
            3600.0,
        ),
        ParameterSpec(
            "diagnostics_period",
            1.0,
            "Period [s, wall time] of /diagnostics.",
            0.05,
            60.0,
            read_only=True,
        ),
        ParameterSpec(
            "ready_subscribers",
            0,
            "Subscriptions /dm/command must have matched before 'feedforward: ready' (the "
            "plant and recorder that must get the first command; the graph sets it).",
            0,
            64,
            read_only=True,
        ),
        ParameterSpec(
            "sync_temperature",
            False,
            "Lockstep: also count /dm/temperature/raw samples and compute a set point only "
            "once the estimate of every sample received before it has arrived (the estimate "
            "and the set point come from different publishers, which DDS does not order).",
            read_only=True,
        ),
        ParameterSpec(
            "sync_timeout",
            1.0,
            "Lockstep with sync_temperature: wall seconds after a raw sample's arrival that a "
            "set point waits for its estimate before using the newest one (counted, WARN).",
            0.001,
            60.0,
            read_only=True,
        ),
        ParameterSpec(
            OBSERVER_PREFIX + "kp",
            observer_defaults.kp,
            "Observer PI proportional gain (normalised by the observer gain).",
            0.0,
            1.0,
        ),
        ParameterSpec(
            OBSERVER_PREFIX + "ki",
            observer_defaults.ki,
            "Observer PI integral gain per iteration (normalised by the observer gain).",
            0.001,
            1.0,
        ),
        ParameterSpec(
            OBSERVER_PREFIX + "iterations",
            observer_defaults.iterations,
            "Observer PI iterations per set point at most (count; mode 'observer' only).",
            *OBSERVER_ITERATIONS_RANGE,
        ),
        ParameterSpec(
            OBSERVER_PREFIX + "tolerance",
            observer_defaults.tolerance,
            "Observer stops after an update that moved no actuator by more than this, V "
            "(0: every iteration runs; mode 'observer' only).",
            *OBSERVER_TOLERANCE_RANGE,
        ),
    ]
    specs += [
        ParameterSpec(
            CALIBRATION_VERDICT,
            "",
            "The calibration's verdict on this parameters file (informational; '' when no "
            "calibration wrote it): anything but 'trusted' is logged and reported on "
            "/diagnostics as 'feedforward: calibration'.",
            choices=list(VERDICTS),
            read_only=True,
        ),
        ParameterSpec(
            CALIBRATION_REASONS,
            [""],
            "The calibration's reasons for its verdict (informational).",
            read_only=True,
        ),
    ]
    specs += [
        ParameterSpec(
            LAW_PREFIX + name,
            [float(getattr(law_defaults, name))],
            f"Temperature law {name}: {LAW_UNITS[name]}; length 1 (all actuators) or "
            "rows*cols (row-major map).",
            check=_double_array_check(LAW_PREFIX + name),
        )
        for name in LAW_FIELDS
    ]
    specs += [
        ParameterSpec(
            COMPENSATION_PREFIX + name,
            float(getattr(compensation_defaults, name)),
            f"Effect compensation, {COMPENSATION_DESCRIPTIONS[name]}.",
            low,
            high,
        )
        for name, (low, high) in COMPENSATION_RANGES.items()
    ]
    return specs
