"""Calibrate every actuator's resonance law from a characterisation bag (pure, no rclpy).

Per actuator i the resonance reading follows f = f0_i + a_T,i (T - T0) + a_V,i |V|. A
characterisation run (a Peltier ramp of the whole mirror, no exposure, and a voltage
program; /dm/resonance, /dm/command and /dm/temperature/raw recorded) gives, at every
reading, the command in force (the last /dm/command stamped before the reading: the sweep
runs under the previous step's command) and the stage temperature (the mean of the valid
sensor readings, linearly interpolated to the reading's stamp: the stage is uniform, and the
sensors' individual offsets average out). :func:`fit_resonance` fits the three parameters
per actuator by least squares, all actuators at once (batched 3 x 3 normal equations), with
1-sigma uncertainties from the residual scatter. A channel with too few readings, or whose
a_T is implausible (not within a factor 2 of the median), is listed as disabled.

:func:`write_thermal_params` writes the result as the thermal node's parameters file
(``resonance.*``, see :mod:`es_thermal.thermal_node`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import yaml

from es_common.arrays import FloatArray, IntArray
from es_msgs_py import bag as bagio
from es_thermal.errors import ResonanceCalibrationError

# The contract's topic names (es_msgs_py.topics imports rclpy; this tool must not need it).
RESONANCE_TOPIC: Final = "/dm/resonance"
COMMAND_TOPIC: Final = "/dm/command"
TEMPERATURE_RAW_TOPIC: Final = "/dm/temperature/raw"
#: Fewest readings per actuator for a fit (three parameters and a residual estimate).
MIN_READINGS: Final = 8
#: A channel's a_T beyond this factor of the median a_T is not a working channel.
A_T_FACTOR: Final = 2.0
#: Fewest distinct stage temperatures a fit needs [degC of span].
MIN_TEMPERATURE_SPAN: Final = 1.0
NODE_NAME: Final = "thermal"


@dataclass(frozen=True)
class ResonanceFit:
    """The fitted laws; maps are (R, C).

    Attributes:
        f0_hz, a_t_hz_per_degc, a_v_hz_per_v: the fitted parameters [Hz, Hz/degC, Hz/V].
        f0_sd_hz, a_t_sd, a_v_sd: their 1-sigma uncertainties (same units).
        residual_hz: rms residual per actuator [Hz].
        readings: readings used per actuator.
        reference_temperature: T0 [degC].
        disabled: row-major indices of the channels that could not be calibrated.

    """

    f0_hz: FloatArray
    a_t_hz_per_degc: FloatArray
    a_v_hz_per_v: FloatArray
    f0_sd_hz: FloatArray
    a_t_sd: FloatArray
    a_v_sd: FloatArray
    residual_hz: FloatArray
    readings: IntArray
    reference_temperature: float
    disabled: tuple[int, ...]

    @property
    def noise_hz(self) -> float:
        """Median residual rms over the working channels [Hz] (the reading noise)."""
        keep = np.ones(self.residual_hz.size, bool)
        keep[list(self.disabled)] = False
        return float(np.median(self.residual_hz.ravel()[keep]))


def command_in_force(
    times: FloatArray, command_times: FloatArray, commands: FloatArray
) -> FloatArray:
    """Return the command (K, R, C) in force at each time (K,): the last one stamped before it.

    Times before the first command get 0 V (nothing applied yet).
    """
    index = np.searchsorted(command_times, times, side="left") - 1
    out = np.zeros((times.size, *commands.shape[1:]))
    has = index >= 0
    out[has] = commands[index[has]]
    return out


def fit_resonance(
    times: FloatArray,
    resonance: FloatArray,
    voltage: FloatArray,
    temperature: FloatArray,
    reference_temperature: float,
) -> ResonanceFit:
    """Fit f = f0 + a_T (T - T0) + a_V |V| per actuator.

    Args:
        times: reading stamps (K,) [s] (only for the shapes' sake; order is irrelevant).
        resonance: readings (K, R, C) [Hz], NaN where not swept.
        voltage: command in force at each reading (K, R, C) [V].
        temperature: actuator temperature at each reading, (K,) uniform or (K, R, C) [degC].
        reference_temperature: T0 [degC].

    Raises:
        ResonanceCalibrationError: shapes that do not fit, too small a temperature span, or
            no channel with enough readings.

    """
    k, rows, cols = resonance.shape
    if times.shape != (k,) or voltage.shape != resonance.shape:
        raise ResonanceCalibrationError("readings, stamps and commands do not line up")
    temp = np.broadcast_to(
        temperature[:, None, None] if temperature.ndim == 1 else temperature, resonance.shape
    ).reshape(k, -1)
    f = resonance.reshape(k, -1)
    used = np.isfinite(f) & np.isfinite(temp)
    if not np.any(used):
        raise ResonanceCalibrationError("no finite resonance reading with a temperature")
    span = float(np.ptp(temp[used]))
    if span < MIN_TEMPERATURE_SPAN:
        raise ResonanceCalibrationError(
            f"stage temperature spans {span:.3g} degC; a characterisation needs a ramp of at "
            f"least {MIN_TEMPERATURE_SPAN:g} degC"
        )
    w = used.astype(float)
    x = np.stack(
        [np.ones_like(f), np.where(used, temp - reference_temperature, 0.0),
         np.abs(voltage.reshape(k, -1))], axis=-1,
    )  # fmt: skip
    y = np.where(used, f, 0.0)
    xtx = np.einsum("kn,kni,knj->nij", w, x, x)
    xty = np.einsum("kn,kni,kn->ni", w, x, y)
    count = used.sum(axis=0)
    enough = count >= MIN_READINGS
    enough &= np.abs(np.linalg.det(np.where(enough[:, None, None], xtx, np.eye(3)))) > 0.0
    if not np.any(enough):
        raise ResonanceCalibrationError(
            f"no actuator has {MIN_READINGS} resonance readings over the temperature ramp"
        )
    safe = np.where(enough[:, None, None], xtx, np.eye(3))
    beta = np.linalg.solve(safe, np.where(enough[:, None], xty, 0.0)[..., None])[..., 0]
    residual = np.where(used, y - np.einsum("kni,ni->kn", x, beta), 0.0)
    dof = np.maximum(count - 3, 1)
    variance = (residual**2).sum(axis=0) / dof
    cov = np.linalg.inv(safe) * variance[:, None, None]
    sd = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    a_t = beta[:, 1]
    median = float(np.median(a_t[enough]))
    plausible = (a_t * np.sign(median) >= abs(median) / A_T_FACTOR) & (
        a_t * np.sign(median) <= abs(median) * A_T_FACTOR
    )
    working = enough & plausible
    nominal = np.median(beta[working], axis=0) if np.any(working) else beta[enough][0]
    beta = np.where(working[:, None], beta, nominal)
    shape = (rows, cols)
    return ResonanceFit(
        f0_hz=beta[:, 0].reshape(shape),
        a_t_hz_per_degc=beta[:, 1].reshape(shape),
        a_v_hz_per_v=beta[:, 2].reshape(shape),
        f0_sd_hz=sd[:, 0].reshape(shape),
        a_t_sd=sd[:, 1].reshape(shape),
        a_v_sd=sd[:, 2].reshape(shape),
        residual_hz=np.sqrt(variance).reshape(shape),
        readings=count.reshape(shape).astype(np.int64),
        reference_temperature=float(reference_temperature),
        disabled=tuple(int(i) for i in np.flatnonzero(~working)),
    )


def calibrate_bag(path: str | Path, reference_temperature: float | None = None) -> ResonanceFit:
    """Read a characterisation bag and fit every actuator's resonance law.

    ``reference_temperature`` (T0) defaults to the stage temperature's mean, rounded to
    0.1 degC.

    Raises:
        ResonanceCalibrationError: missing or empty topics, a corrupt bag, mismatched grids,
            no time overlap or too little data (one readable line).

    """
    try:
        series = bagio.read_bag(path, [RESONANCE_TOPIC, COMMAND_TOPIC, TEMPERATURE_RAW_TOPIC])
    except bagio.BagError as err:
        raise ResonanceCalibrationError(str(err)) from None
    arrays = {}
    for topic in (RESONANCE_TOPIC, COMMAND_TOPIC, TEMPERATURE_RAW_TOPIC):
        s = series[topic]
        if s.values is None or len(s) == 0:
            raise ResonanceCalibrationError(f"{topic}: no messages in {path}")
        order = np.argsort(s.times, kind="stable")
        arrays[topic] = (s.times[order], s.values[order])
    r_times, resonance = arrays[RESONANCE_TOPIC]
    c_times, commands = arrays[COMMAND_TOPIC]
    t_times, raw = arrays[TEMPERATURE_RAW_TOPIC]
    if resonance.ndim != 3:
        raise ResonanceCalibrationError(f"{RESONANCE_TOPIC} is not a grid")
    if commands.shape[1:] != resonance.shape[1:]:
        raise ResonanceCalibrationError(
            f"{COMMAND_TOPIC} grid {commands.shape[1:]} != {RESONANCE_TOPIC} grid "
            f"{resonance.shape[1:]}"
        )
    stage = _stage_temperature(raw)
    keep = np.isfinite(stage)
    if np.count_nonzero(keep) < 2:
        raise ResonanceCalibrationError(f"{TEMPERATURE_RAW_TOPIC}: fewer than 2 valid samples")
    t_times, stage = t_times[keep], stage[keep]
    inside = (r_times >= t_times[0]) & (r_times <= t_times[-1]) & (r_times > c_times[0])
    if not np.any(inside):
        raise ResonanceCalibrationError(
            "the resonance readings do not overlap the temperatures and commands in time"
        )
    r_times, resonance = r_times[inside], resonance[inside]
    temperature = np.interp(r_times, t_times, stage)
    t0 = (
        round(float(np.mean(stage)), 1)
        if reference_temperature is None
        else float(reference_temperature)
    )
    voltage = command_in_force(r_times, c_times, commands)
    return fit_resonance(r_times, resonance, voltage, temperature, t0)


def _stage_temperature(raw: FloatArray) -> FloatArray:
    """Return the mean of each sample's finite readings (NaN where none), (K,) [degC]."""
    flat = raw.reshape(raw.shape[0], -1)
    finite = np.isfinite(flat)
    total = np.where(finite, flat, 0.0).sum(axis=1)
    count = finite.sum(axis=1)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def thermal_parameters(fit: ResonanceFit) -> dict[str, object]:
    """Return the thermal node's ``resonance.*`` parameters (and the grid) for ``fit``."""
    rows, cols = fit.f0_hz.shape

    def flat(values: FloatArray) -> list[float]:
        return [float(v) for v in values.ravel()]

    params: dict[str, object] = {
        "rows": rows,
        "cols": cols,
        "resonance.f0_hz": flat(fit.f0_hz),
        "resonance.a_t_hz_per_degc": flat(fit.a_t_hz_per_degc),
        "resonance.a_v_hz_per_v": flat(fit.a_v_hz_per_v),
        "resonance.f0_sd_hz": flat(fit.f0_sd_hz),
        "resonance.a_t_sd": flat(fit.a_t_sd),
        "resonance.a_v_sd": flat(fit.a_v_sd),
        "resonance.reference_temperature": fit.reference_temperature,
        "resonance.noise_hz": fit.noise_hz,
    }
    if fit.disabled:
        params["resonance.disabled_channels"] = list(fit.disabled)
    return params


def write_thermal_params(fit: ResonanceFit, path: str | Path) -> None:
    """Write ``fit`` as a ROS 2 parameters file of the ``thermal`` node.

    Raises:
        OSError: the file cannot be written.

    """
    document = {NODE_NAME: {"ros__parameters": thermal_parameters(fit)}}
    Path(path).write_text(yaml.safe_dump(document, sort_keys=False, width=100))
