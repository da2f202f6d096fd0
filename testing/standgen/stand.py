"""One test-stand recording: drive, actuator physics, sensors, interferometer and defects.

Signal chain per actuator (time t from the start of the recording, all on the command clock):

1. the signal generator's program V(t) (:mod:`standgen.program`); /dm/command records V(t_k);
2. ``delay``: the actuator is driven by V(t - d), evaluated exactly (fractions of a period);
3. ``frequency_dispersion``: Debye relaxation of the drive;
4. ``hysteresis``: Prandtl-Ishlinskii operator on the drive;
5. temperatures: Peltier base profile + a fixed offset per actuator (the mount); the actuator
   adds ``self_heating`` (dielectric loss ~ |V_ac dV/dt|, mean f A^2 for a sine); the sensor
   reads the mount through ``sensor_lag``, plus noise and quantisation;
6. the hyperbolic law at the actuator temperature with ``temperature_curvature`` (m3, k3),
   M scaled by ``drift`` (aging); then ``coupling`` through the face sheet and
   ``thermal_expansion``;
7. interferometer: white noise and a 0.1 nm quantisation step.

Defects: a fraction of displacement messages dropped at random, a gap in the temperature
topic, optional holes in the command topic.

Recording faults (:mod:`standgen.faults`): a weak or dead actuator scales its displacement
(before coupling); a frozen, flat or jumping temperature sensor; the displacement logger's
clock rate and late, bursty receive stamps change /dm/displacement's stamps only (the
samples stay where they were taken). ``independent_drive``: every actuator its own program.
Effects in no registry list (:mod:`standgen.unlisted`): ``slew_limit`` and
``amplifier_droop`` on the drive after the delay, ``thermal_gradient`` on the actuator
temperature, ``creep`` on the actuator's displacement (before coupling),
``periodic_nonlinearity`` on the interferometer's reading.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt

from standgen._typing import FloatArray
from standgen.effects import Effects
from standgen.faults import BURST_SPACING_S, Faults, ReceiveJitter
from standgen.operators import (
    aging_gain,
    debye_relaxation,
    first_order_lag,
    laplacian,
    prandtl_ishlinskii,
)
from standgen.physics import Law
from standgen.program import (
    IndependentProgram,
    PeltierProfile,
    VoltageProgram,
    make_independent_program,
    make_program,
)
from standgen.ranges import range_of
from standgen.unlisted import (
    Unlisted,
    crept,
    drooped,
    gradient_offset,
    periodic_error,
    slew_limited,
)

#: Temperature topic layouts: per-actuator sensors, one sensor for the grid, a grid estimate.
TEMPERATURE_KINDS: Final = ("raw", "raw_single", "grid")
#: Interferometer quantisation step [m] and NTC read-out step [degC].
INTERFEROMETER_STEP_M: Final = 0.1e-9
SENSOR_STEP_DEGC: Final = 0.01
#: Cut-off [s] (time constant) separating the drive's DC level from its AC part (self-heating).
AC_SPLIT_TAU_S: Final = 1.6
#: Per-actuator offset of the mount temperature (sd) and of each sensor (sd) [degC].
MOUNT_OFFSET_SD: Final = 0.15
SENSOR_OFFSET_SD: Final = 0.05


class StandConfigError(ValueError):
    """A stand configuration that cannot be simulated."""


@dataclass(frozen=True)
class StandConfig:
    """What one recording looks like (units: s, Hz, m, degC).

    Attributes:
        rows, cols: grid.
        rate_hz: command and interferometer rate (same clock, same stamps).
        temperature_rate_hz: NTC sampling rate.
        duration_s: length of the recording.
        temperature_kind: one of :data:`TEMPERATURE_KINDS`.
        noise_m: interferometer white noise (rms).
        sensor_noise_degc: NTC noise (rms).
        effects: the effects present.
        drop_fraction: share of displacement messages dropped at random.
        temperature_gap: (start, length) [s] of a gap in the temperature topic, or None.
        command_holes: (start, length) [s] of holes in /dm/command.
        seed: random seed (program, spread, noise, drops).
        start_time_s: bag time of the first sample (wall-clock epoch seconds).
        faults: recording faults (:mod:`standgen.faults`).
        unlisted: effects in no list of the product's registry (:mod:`standgen.unlisted`).
        independent_drive: every actuator its own program (edges at different times).

    """

    rows: int = 1
    cols: int = 1
    rate_hz: float = 1000.0
    temperature_rate_hz: float = 10.0
    duration_s: float = 40.0
    temperature_kind: str = "raw"
    noise_m: float = 0.5e-9
    sensor_noise_degc: float = 0.02
    effects: Effects = field(default_factory=Effects)
    drop_fraction: float = 0.0
    temperature_gap: tuple[float, float] | None = None
    command_holes: tuple[tuple[float, float], ...] = ()
    seed: int = 0
    start_time_s: float = 1_795_000_000.0
    faults: Faults = field(default_factory=Faults)
    unlisted: Unlisted = field(default_factory=Unlisted)
    independent_drive: bool = False

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols)."""
        return (self.rows, self.cols)

    @property
    def noise_rms_m(self) -> float:
        """True interferometer noise [m rms]: white noise and quantisation together."""
        return float(np.hypot(self.noise_m, INTERFEROMETER_STEP_M / np.sqrt(12.0)))

    @property
    def sensors(self) -> int:
        """Number of temperature readings per message (row-major grid cells for ``grid``)."""
        return 1 if self.temperature_kind == "raw_single" else self.rows * self.cols

    def check(self) -> None:
        """Raise StandConfigError on a configuration the stand cannot produce."""
        sensor, actuator = self.faults.sensor, self.faults.actuator
        problems = [
            (self.rows >= 1 and self.cols >= 1, "grid must be at least 1 x 1"),
            (self.rate_hz > 0 and self.temperature_rate_hz > 0, "rates must be > 0"),
            (self.duration_s * self.temperature_rate_hz >= 4, "too short for the sensor"),
            (self.temperature_kind in TEMPERATURE_KINDS,
             f"temperature_kind must be one of {TEMPERATURE_KINDS}"),
            (0 <= self.drop_fraction < 1, "drop_fraction must be in [0, 1)"),
            (self.effects.coupling is None or min(self.shape) >= 2, "coupling needs >= 2 x 2"),
            (sensor is None or 0 <= sensor.sensor < self.sensors,
             "the faulty sensor's index is not a sensor of this layout"),
            (actuator is None or 0 <= actuator.index < self.rows * self.cols,
             "the faulty actuator's index is not an actuator of this grid"),
            (self.unlisted.thermal_gradient is None or min(self.shape) >= 3,
             "thermal_gradient needs >= 3 x 3"),
        ]
        for ok, message in problems:
            if not ok:
                raise StandConfigError(message)


@dataclass(frozen=True)
class Recording:
    """A recording's topics (times in s since ``config.start_time_s``) and its truth.

    Attributes:
        command_times (Nc,), command (Nc, R, C) [V];
        displacement_times (Nd,), displacement (Nd, R, C) [m] (noisy, as measured);
        temperature_times (Nt,), temperature (Nt, S) sensors or (Nt, R, C) grid [degC];
        temperature_topic: /dm/temperature/raw or /dm/temperature.
        truth_displacement: noise-free displacement at ``displacement_times`` [m].
        actuator_temperature: actuator temperature at ``displacement_times`` [degC].
        law: the per-actuator law coefficients used (a weak or dead actuator's fault scales
            its displacement, not this law).
        displacement_sample_times: when each displacement message was sampled, on the
            command clock [s]; ``displacement_times`` are its stamps (they differ only under
            a clock-rate or receive-jitter fault).

    """

    config: StandConfig
    command_times: FloatArray
    command: FloatArray
    displacement_times: FloatArray
    displacement: FloatArray
    temperature_times: FloatArray
    temperature: FloatArray
    temperature_topic: str
    truth_displacement: FloatArray
    actuator_temperature: FloatArray
    law: Law
    displacement_sample_times: FloatArray


def spread_law(rng: np.random.Generator, shape: tuple[int, int], effects: Effects) -> Law:
    """Return the nominal law with the stand table's per-actuator scatter and any curvature."""
    base = Law()
    curvature = effects.temperature_curvature
    spread_m2 = range_of("stand", "spread_m2").low
    spread_k2 = range_of("stand", "spread_k2").low
    return Law(
        m1=np.full(shape, base.m1),
        m2=base.m2 * (1 + spread_m2 * rng.standard_normal(shape)),
        m3=np.full(shape, curvature.m3 if curvature else 0.0),
        k1=np.full(shape, base.k1),
        k2=base.k2 * (1 + spread_k2 * rng.standard_normal(shape)),
        k3=np.full(shape, curvature.k3 if curvature else 0.0),
    )


def _interp_rows(t_new: FloatArray, t: FloatArray, values: FloatArray) -> FloatArray:
    """Linear interpolation of ``values`` (N, ...) sampled at uniform ``t`` onto ``t_new``."""
    pos = np.clip((t_new - t[0]) / (t[1] - t[0]), 0, t.size - 1)
    i = np.minimum(np.floor(pos).astype(np.intp), t.size - 2)
    frac = (pos - i).reshape(-1, *([1] * (values.ndim - 1)))
    return np.asarray(values[i] * (1 - frac) + values[i + 1] * frac, np.float64)


def true_law(config: StandConfig) -> Law:
    """Return the per-actuator law :func:`simulate` uses for ``config`` (its first draw)."""
    return spread_law(np.random.default_rng(config.seed), config.shape, config.effects)


def mid_temperature(config: StandConfig) -> float:
    """Middle of the base (Peltier) temperature's range over the recording [degC]."""
    dt = 1.0 / config.rate_hz
    base = PeltierProfile(config.duration_s)(
        np.arange(round(config.duration_s * config.rate_hz), dtype=np.float64) * dt, dt)
    return float(0.5 * (base.min() + base.max()))


def drive(config: StandConfig,
          program: VoltageProgram | IndependentProgram | Callable[[FloatArray], FloatArray],
          t: FloatArray) -> FloatArray:
    """Return the drive reaching the actuator's strain (N, R, C).

    Delay, the amplifier's slew limit and droop (unlisted), dispersion, PI hysteresis.
    """
    e, u = config.effects, config.unlisted
    dt = 1.0 / config.rate_hz
    v = program(t - (e.delay.delay_s if e.delay else 0.0))
    if u.slew_limit:
        v = slew_limited(v, dt, u.slew_limit.rate_v_per_s)
    if u.amplifier_droop:
        v = drooped(v, dt, u.amplifier_droop)
    if e.frequency_dispersion:
        v = debye_relaxation(v, dt, e.frequency_dispersion.strength,
                             e.frequency_dispersion.corner_hz)
    if e.hysteresis:
        v = prandtl_ishlinskii(v, e.hysteresis.thresholds_v, e.hysteresis.weights)
    return v


def self_heating_excess(config: StandConfig, v: FloatArray) -> FloatArray:
    """Actuator excess temperature (N, R, C) [degC] from dielectric loss of the drive ``v``."""
    heating = config.effects.self_heating
    if heating is None:
        return np.zeros_like(v)
    dt = 1.0 / config.rate_hz
    ac = v - first_order_lag(v, dt, AC_SPLIT_TAU_S)
    loss = 0.5 * heating.gain * np.abs(ac * np.gradient(v, dt, axis=0))
    return first_order_lag(loss, dt, heating.tau_s)


def _defects(config: StandConfig, rng: np.random.Generator, t: FloatArray,
             t_temp: FloatArray) -> tuple[npt.NDArray[np.bool_], ...]:
    keep_disp = rng.random(t.size) >= config.drop_fraction
    keep_temp = np.ones(t_temp.size, bool)
    if config.temperature_gap is not None:
        start, length = config.temperature_gap
        keep_temp &= ~((t_temp >= start) & (t_temp < start + length))
    keep_cmd = np.ones(t.size, bool)
    for start, length in config.command_holes:
        keep_cmd &= ~((t >= start) & (t < start + length))
    return keep_cmd, keep_disp, keep_temp


def receive_stamps(faults: Faults, sample_times: FloatArray,
                   rng: np.random.Generator) -> FloatArray:
    """Stamps [s] of displacement messages sampled at ``sample_times`` (command clock).

    A clock-rate fault stamps them on the logger's own clock, t (1 + ppm 1e-6); receive
    jitter delays each by an exponential draw and every message of a burst window until the
    window's end plus its lateness; receive order stays sample order.
    """
    stamps = sample_times.copy()
    if faults.clock_rate:
        stamps = stamps * (1.0 + faults.clock_rate.ppm * 1e-6)
    jitter: ReceiveJitter | None = faults.receive_jitter
    if jitter:
        stamps = stamps + rng.exponential(jitter.mean_s, stamps.size)
        for start, length, late in jitter.bursts:
            inside = np.flatnonzero((sample_times >= start) & (sample_times < start + length))
            stamps[inside] = start + length + late + np.arange(inside.size) * BURST_SPACING_S
        stamps = np.maximum.accumulate(stamps)
    return stamps


def _sensor_fault(faults: Faults, t_temp: FloatArray, sensed: FloatArray) -> FloatArray:
    """Apply a temperature sensor fault to the readings ``sensed`` (Nt, S) or (Nt, R, C)."""
    fault = faults.sensor
    if fault is None:
        return sensed
    out = sensed.reshape(t_temp.size, -1).copy()
    column = out[:, fault.sensor]
    if fault.kind == "frozen":
        before = np.flatnonzero(t_temp < fault.start_s)
        column[t_temp >= fault.start_s] = column[before[-1]] if before.size else column[0]
    elif fault.kind == "flat":
        column[:] = fault.value_degc
    else:
        for time_s, step in fault.jumps:
            column[t_temp >= time_s] += step
    return out.reshape(sensed.shape)


def simulate(config: StandConfig, drive_program: Callable[[FloatArray], FloatArray] | None = None
             ) -> Recording:
    """Simulate one recording (see the module docstring).

    ``drive_program``: voltages (N, R, C) at times (N,) to drive instead of the drawn program
    (a feedforward's commands, for a closed loop on the stand); every random draw stays the
    same, so the law, the temperatures and the noise are those of the drawn program's record.

    Raises:
        StandConfigError: an impossible configuration.

    """
    config.check()
    rng = np.random.default_rng(config.seed)
    shape, e, u, faults = config.shape, config.effects, config.unlisted, config.faults
    dt = 1.0 / config.rate_hz
    t = np.arange(round(config.duration_s * config.rate_hz), dtype=np.float64) * dt
    law = spread_law(rng, shape, e)
    program: VoltageProgram | IndependentProgram | Callable[[FloatArray], FloatArray] = (
        make_independent_program(rng, config.duration_s, shape, config.rate_hz)
        if config.independent_drive else make_program(rng, config.duration_s, shape,
                                                      config.rate_hz))
    if drive_program is not None:
        program = drive_program
    command = program(t)
    v = drive(config, program, t)

    base = PeltierProfile(config.duration_s)(t, dt)
    mount = base[:, None, None] + MOUNT_OFFSET_SD * rng.standard_normal(shape)
    actuator = mount + self_heating_excess(config, v)
    if u.thermal_gradient:
        actuator = actuator + gradient_offset(actuator, dt, u.thermal_gradient)
    seen = first_order_lag(mount, dt, e.sensor_lag.tau_s) if e.sensor_lag else mount

    gain = aging_gain(t, e.drift.fraction, e.drift.tau_s, e.drift.nu) if e.drift else np.ones(
        t.size)
    z = law.displacement(v, actuator, gain[:, None, None])
    if faults.actuator:
        scale = np.ones(shape)
        scale.flat[faults.actuator.index] = faults.actuator.fraction
        z = z * scale
    if u.creep:
        z = crept(z, dt, u.creep)
    if e.coupling:
        z = z + e.coupling.coefficient * laplacian(z)
    if e.thermal_expansion:
        z = z + e.thermal_expansion.alpha_m_per_degc * (
            actuator - e.thermal_expansion.reference_degc)
    measured = z + config.noise_m * rng.standard_normal(z.shape)
    if u.periodic_nonlinearity:
        measured = measured + periodic_error(z, u.periodic_nonlinearity)
    measured = np.round(measured / INTERFEROMETER_STEP_M) * INTERFEROMETER_STEP_M

    phase = 0.37 / config.temperature_rate_hz  # the NTC clock is not the command clock
    t_temp = np.arange(phase, t[-1], 1.0 / config.temperature_rate_hz)
    sensed = _interp_rows(t_temp, t, seen)
    if config.temperature_kind == "raw_single":
        sensed = sensed.mean(axis=(1, 2))[:, None]
    elif config.temperature_kind == "raw":
        sensed = sensed.reshape(t_temp.size, -1)
    sensed = sensed + SENSOR_OFFSET_SD * rng.standard_normal(sensed.shape[1:])
    sensed = sensed + config.sensor_noise_degc * rng.standard_normal(sensed.shape)
    sensed = np.round(sensed / SENSOR_STEP_DEGC) * SENSOR_STEP_DEGC
    sensed = _sensor_fault(faults, t_temp, sensed)

    keep_cmd, keep_disp, keep_temp = _defects(config, rng, t, t_temp)
    stamps = receive_stamps(faults, t[keep_disp], rng)  # last draws: the rest is unchanged
    topic = "/dm/temperature" if config.temperature_kind == "grid" else "/dm/temperature/raw"
    return Recording(
        config=config,
        command_times=t[keep_cmd], command=command[keep_cmd],
        displacement_times=stamps, displacement=measured[keep_disp],
        temperature_times=t_temp[keep_temp], temperature=sensed[keep_temp],
        temperature_topic=topic,
        truth_displacement=z[keep_disp], actuator_temperature=actuator[keep_disp],
        law=law, displacement_sample_times=t[keep_disp],
    )
