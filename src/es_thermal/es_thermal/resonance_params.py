"""The thermal node's ``resonance.*`` parameters (self-sensing) and the fusion they build.

``resonance.f0_hz`` empty (the default) switches self-sensing off: the node then neither
subscribes /dm/resonance nor /dm/command and behaves as without this feature. The
per-actuator laws and their uncertainties are what ``calibrate_resonance`` writes; arrays
have length 1 (same for all actuators) or R*C (row-major map).
"""

from __future__ import annotations

import array
from collections.abc import Mapping

from es_node_runtime.param_spec import ParameterSpec, ParameterValues
from es_thermal.selfsensing import (
    FusionConfig,
    ResonanceCalibration,
    SelfSensingFusion,
)

_FUSION = FusionConfig()


def _check_numbers(value: object) -> str | None:
    if isinstance(value, bytes | bytearray) and not value:
        return None  # the untyped empty default
    ok = isinstance(value, list | tuple | array.array) and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value
    )
    return None if ok else "must be a list of numbers"


def _array(name: str, default: list[float], text: str) -> ParameterSpec:
    return ParameterSpec(
        name, default, text, check=_check_numbers, read_only=True, dynamic_typing=True
    )


SPECS: tuple[ParameterSpec, ...] = (
    _array(
        "resonance.f0_hz", [], "Self-sensing: resonance at T0 and 0 V per actuator, Hz; empty: off."
    ),
    _array("resonance.a_t_hz_per_degc", [3227.0], "Self-sensing: a_T per actuator, Hz/degC."),
    _array("resonance.a_v_hz_per_v", [-80.0], "Self-sensing: a_V per actuator, Hz/V."),
    _array("resonance.f0_sd_hz", [0.0], "Self-sensing: 1-sigma uncertainty of f0, Hz."),
    _array("resonance.a_t_sd", [0.0], "Self-sensing: 1-sigma uncertainty of a_T, Hz/degC."),
    _array("resonance.a_v_sd", [0.0], "Self-sensing: 1-sigma uncertainty of a_V, Hz/V."),
    _array(
        "resonance.disabled_channels", [], "Self-sensing: row-major channels never used."
    ),
    ParameterSpec(
        "resonance.reference_temperature", 40.0, "Self-sensing: T0 of the laws, degC.",
        -273.0, 1000.0, read_only=True,
    ),
    ParameterSpec(
        "resonance.noise_hz", _FUSION.noise_hz, "Self-sensing: rms noise of a reading, Hz.",
        1e-6, 1e7, read_only=True,
    ),
    ParameterSpec(
        "resonance.drift", _FUSION.drift,
        "Self-sensing: random walk of the model's error per actuator, degC/sqrt(s) "
        "(physical; grows by 1/sqrt(time_scale)).",
        1e-9, 100.0, read_only=True,
    ),
    ParameterSpec(
        "resonance.gate_degc", _FUSION.gate_degc,
        "Self-sensing: a reading this far off the estimate is dropped as implausible, degC.",
        1e-6, 1000.0, read_only=True,
    ),
    ParameterSpec(
        "resonance.acquire_gate_degc", _FUSION.acquire_gate_degc,
        "Self-sensing: the same for a channel without a correction yet, degC.",
        1e-6, 1000.0, read_only=True,
    ),
    ParameterSpec(
        "resonance.stuck_band_degc", _FUSION.stuck_band_degc,
        "Self-sensing: a reading repeating while the model moves this much is stuck, degC.",
        1e-6, 1000.0, read_only=True,
    ),
    ParameterSpec(
        "resonance.stale_after", _FUSION.stale_after,
        "Self-sensing: a channel without an accepted reading this long is stale and its "
        "correction dropped, s of sample time.",
        1e-3, 1e7, read_only=True,
    ),
)  # fmt: skip


def fusion_from_parameters(
    values: Mapping[str, object], count: int, time_scale: float
) -> SelfSensingFusion | None:
    """Build the fusion from declared parameter values; ``None`` when ``resonance.f0_hz`` is empty.

    Raises:
        ValueError: arrays of the wrong length, NaN, a zero a_T or a disabled channel off the
            grid (:class:`es_thermal.selfsensing.CalibrationError`); the message says which.

    """
    typed = ParameterValues(values)
    numbers = typed.get_floats
    f0 = numbers("resonance.f0_hz")
    if not f0:
        return None
    calibration = ResonanceCalibration.from_values(
        count,
        f0_hz=f0,
        a_t_hz_per_degc=numbers("resonance.a_t_hz_per_degc"),
        a_v_hz_per_v=numbers("resonance.a_v_hz_per_v"),
        reference_temperature=typed.get_float("resonance.reference_temperature"),
        f0_sd_hz=numbers("resonance.f0_sd_hz"),
        a_t_sd=numbers("resonance.a_t_sd"),
        a_v_sd=numbers("resonance.a_v_sd"),
    )
    config = FusionConfig(
        noise_hz=typed.get_float("resonance.noise_hz"),
        drift=typed.get_float("resonance.drift"),
        gate_degc=typed.get_float("resonance.gate_degc"),
        acquire_gate_degc=typed.get_float("resonance.acquire_gate_degc"),
        stale_after=typed.get_float("resonance.stale_after"),
        stuck_band_degc=typed.get_float("resonance.stuck_band_degc"),
    ).time_scaled(time_scale)
    disabled = tuple(int(v) for v in numbers("resonance.disabled_channels"))
    return SelfSensingFusion(calibration, config, disabled)
