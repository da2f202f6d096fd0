"""Temperature-compensated feedforward: set points and temperatures in, voltages out.

Pure numpy core of the feedforward node (no rclpy). Modes (``Mode``), all per actuator:

- ``inverse_hyperbolic`` (default): V = P^-1(z, T) of the hyperbolic model;
- ``inverse_quadratic``: V = sqrt(z L / M(T)) (the thesis's hardware scheme);
- ``linearized_dmax``: V = V_max(T) + (z - z_sat(T)/3) / d_max(T), with the model's own error
  of that linearisation reported per actuator (:func:`linearization_error_bound` for a span);
- ``observer``: the hyperbolic forward model as observer and a PI loop driving its output to
  the set point; the loop runs at most ``iterations`` times per set point, until an update
  moves no actuator by more than ``tolerance`` (the observer has no dynamics, so it is a fast
  inner loop), its integrator warm-starts from the last set point and its gain is scheduled
  on the observer's local gain;
- ``uncompensated``: the hyperbolic inverse at the fixed ``reference_temperature``, no
  temperature input needed: the baseline reports compare against.

The compensation stages of the effects (:meth:`es_physics.effects.Effect.compensator`, from
the ``compensation.*`` parameters, chained in model order) are applied around the model in
every mode (temperature-based ones use the reference temperature in ``uncompensated``).

Safety: the output is always finite and within [0, v_limit]. A missing, stale (older than
``temperature_timeout``) or invalid (non-finite or outside ``PLAUSIBLE_TEMPERATURE``)
temperature estimate holds the whole last good command; a non-finite set point element holds
that actuator's last voltage (``Status.INVALID``).

The configuration types (:class:`Mode`, :class:`ObserverGains`, :class:`FeedforwardConfig`)
live in :mod:`es_feedforward.feedforward_config` and are re-exported here.
"""

from __future__ import annotations

from typing import Final, NamedTuple

import numpy as np
import numpy.typing as npt

from es_feedforward.errors import FeedforwardConfigError, FeedforwardInputError
from es_feedforward.feedforward_config import (
    DEFAULT_REFERENCE_TEMPERATURE,
    DEFAULT_TEMPERATURE_TIMEOUT,
    OPERATING_T_STAR,
    PLAUSIBLE_TEMPERATURE,
    FeedforwardConfig,
    Mode,
    ObserverGains,
)
from es_feedforward.kernels import (
    Backend,
    default_backend,
    fused_hyperbolic_inverse,
    fused_linearized,
    fused_reach_status,
    observer_command,
    prepare,
)
from es_physics.effects import Compensator, in_model_order
from es_physics.laws import (
    CODE_CLIPPED_HIGH,
    CODE_CLIPPED_LOW,
    CODE_INVALID,
    CODE_OK,
    RATIO_CAP,
    CompiledLaws,
    InverseResult,
    LawsAtTemperature,
    StatusArray,
    limit_voltages,
)
from es_physics.params import FloatArray

__all__ = [
    "DEFAULT_REFERENCE_TEMPERATURE",
    "DEFAULT_TEMPERATURE_TIMEOUT",
    "OPERATING_T_STAR",
    "PLAUSIBLE_TEMPERATURE",
    "REACH_MARGIN",
    "SETPOINT_CEILING",
    "CommandResult",
    "Feedforward",
    "FeedforwardConfig",
    "Mode",
    "ObserverGains",
    "linearization_error_bound",
]

#: Set points above this [m] are far beyond any reach: cut here to keep the arithmetic finite.
SETPOINT_CEILING: Final = 1.0
#: Relative margin below the reach of ``v_limit`` under which set points skip the inverse that
#: only reports their status (far above the inverse's rounding, ~1e-15).
REACH_MARGIN: Final = 1e-9


class CommandResult(NamedTuple):
    """One command of the feedforward.

    A named tuple: one is built per set point, in half the time of a frozen dataclass.

    Attributes:
        voltage: voltages [V], grid, finite, in [0, v_limit] (read-only array).
        status: per-actuator :class:`Status` codes (int8 grid, read-only array).
        held: the whole command is the last good one (``problem`` says why).
        problem: why no new command could be computed, or ``None``.
        model_error: linearized_dmax and observer: z_model(V) - z_wanted [m] per actuator.
        worst: the largest code in ``status`` (a plain int).

    """

    voltage: FloatArray
    status: StatusArray
    held: bool = False
    problem: str | None = None
    model_error: FloatArray | None = None
    worst: int = CODE_OK


def linearization_error_bound(laws: LawsAtTemperature, amplitude: npt.ArrayLike) -> FloatArray:
    """Return the largest |z(V) - z_wanted| of ``linearized_dmax`` for |z - z_sat/3| <= amplitude.

    The error e(dV) = z(V_max + dV) - z_sat/3 - d_max dV never rises (d_max is the largest
    slope), so its extremes over [-a, a] (a = amplitude / d_max) are at the two ends.
    """
    dmax = laws.d_max
    v_max = laws.v_max
    dv = np.asarray(amplitude, np.float64) / dmax
    z_mid = laws.z_sat / 3.0
    ends = [
        np.abs(laws.hyperbolic_forward(np.maximum(v_max + s * dv, 0.0)) - z_mid - s * dmax * dv)
        for s in (-1.0, 1.0)
    ]
    return np.asarray(np.maximum(*ends), np.float64)


class Feedforward:
    """Stateful feedforward for one grid: feed temperatures and set points, get commands.

    States (the compensation stages', e.g. temperature filter, delay slope, hysteresis play;
    observer integrator, last good command) carry over to a new configuration of the same grid
    via ``previous``.
    """

    #: The compensation stages in model order, by effect name.
    _stages: dict[str, Compensator]
    _integral: FloatArray
    _last_voltage: FloatArray
    _last_status: StatusArray
    _last_worst: int
    _temperature: FloatArray | None
    _temperature_time: float | None
    _temperature_problem: str | None

    def __init__(
        self,
        config: FeedforwardConfig,
        previous: Feedforward | None = None,
        backend: Backend | None = None,
    ) -> None:
        """Build the feedforward for ``config``.

        Args:
            config: the configuration.
            previous: a feedforward of the same grid whose states carry over.
            backend: inner loops (:mod:`es_feedforward.kernels`); ``None``: the default
                (fused when numba is importable, unless ``ES_DM_FEEDFORWARD_KERNELS=numpy``).

        Raises:
            FeedforwardConfigError: the configuration is inconsistent (the reason is the message).
            es_feedforward.kernels.KernelBackendError: the kernels asked for are not available.

        """
        reason = config.reason_to_reject()
        if reason is not None:
            raise FeedforwardConfigError(reason)
        self.config = config
        self.backend = default_backend() if backend is None else backend
        prepare(self.backend, config.mode)  # compile now, not on the first set point
        self._reach: tuple[LawsAtTemperature, tuple[float, FloatArray, FloatArray]] | None = None
        #: (laws, integral, tanh(q integral)) of the observer's last set point, or None
        self._observer_tanh: tuple[LawsAtTemperature, FloatArray, FloatArray] | None = None
        shape = config.shape
        comp = config.compensation
        self._laws_compiled = CompiledLaws(config.params, shape)
        self._reference_T = np.full(shape, config.reference_temperature)
        self._reference_laws = self._laws_compiled.at(self._reference_T)
        carry = previous is not None and previous.config.shape == shape
        self._stages = {}
        for effect in in_model_order():
            # carried over into new objects: ``previous`` stays untouched and usable until
            # the caller swaps this one in (a rejected reload changes nothing); a stage
            # new to the configuration starts from the command in force (bumpless)
            stage = effect.compensator(
                comp.of(effect.name),
                shape,
                previous._stages.get(effect.name) if previous is not None and carry else None,
                previous._last_voltage if previous is not None and carry else None,
            )
            if stage is not None:
                self._stages[effect.name] = stage
        #: the stages that reshape the drive, in model order
        self._drive_stages = [s for s in self._stages.values() if s.reshapes_drive]
        #: the command is the plain hyperbolic inverse: where the fused kernels take it (their
        #: first pass also refuses every set point the cleaning in :meth:`command` would
        #: change), it is tried first, for the whole command
        self._plain_hyperbolic = (
            config.mode in (Mode.INVERSE_HYPERBOLIC, Mode.UNCOMPENSATED) and not self._stages
        )
        if previous is not None and carry:
            self._integral = previous._integral
            self._last_voltage = previous._last_voltage
            self._last_status = previous._last_status
            self._last_worst = previous._last_worst
            self._temperature = previous._temperature
            self._temperature_time = previous._temperature_time
            self._temperature_problem = previous._temperature_problem
            # bumpless switch: a new observer starts from the command being applied
            if previous.config.mode is not Mode.OBSERVER:
                self._integral = np.array(self._last_voltage)
        else:
            self._integral = np.zeros(shape)
            self._last_voltage = np.zeros(shape)
            self._last_status = np.zeros(shape, np.int8)
            self._last_worst = CODE_OK
            self._last_voltage.flags.writeable = False
            self._last_status.flags.writeable = False
            self._temperature = None
            self._temperature_time = None
            self._temperature_problem = "no temperature received yet"
        self._laws: LawsAtTemperature | None = None
        if self._temperature is not None:
            self._laws = self._laws_compiled.at(self._temperature)

    def compensation_counters(self) -> dict[str, int]:
        """Return the stages' counts of commands not compensated fully (``<effect>.<count>``)."""
        return {f"{name}.{key}": value for name, stage in self._stages.items()
                for key, value in stage.counters().items()}

    @property
    def needs_temperature(self) -> bool:
        """Whether the mode uses measured temperatures (all but ``uncompensated``)."""
        return self.config.mode is not Mode.UNCOMPENSATED

    @property
    def last_voltage(self) -> FloatArray:
        """The last good command [V] (zeros before the first)."""
        return self._last_voltage

    def update_temperature(self, T: npt.ArrayLike, t: float) -> str | None:
        """Take a temperature estimate [degC] (grid) received at time ``t`` [s].

        Returns:
            ``None`` when accepted, else why it is invalid (the feedforward then holds).

        Raises:
            FeedforwardInputError: ``T`` does not have the grid's shape.

        """
        T = np.asarray(T, np.float64)
        if T.shape != self.config.shape:
            raise FeedforwardInputError(
                f"temperature grid is {T.shape}, expected {self.config.shape}"
            )
        self._temperature_time = t
        low, high = PLAUSIBLE_TEMPERATURE
        if T.size and not (T.min() >= low and T.max() <= high):  # NaN fails too
            bad = int(np.count_nonzero(~np.isfinite(T)))
            implausible = int(np.count_nonzero(np.clip(T, low, high) != T))
            self._temperature_problem = (
                f"temperature estimate has {bad} non-finite value(s)"
                if bad
                else f"temperature estimate has {implausible} value(s) outside {low}..{high} degC"
            )
            self._laws = None
            return self._temperature_problem
        for stage in self._stages.values():
            T = stage.measured_temperature(T, t)
        self._temperature = T
        self._temperature_problem = None
        self._laws = self._laws_compiled.at(self._temperature)
        return None

    def temperature_problem(self, t: float) -> str | None:
        """Return why the temperature cannot be used at time ``t`` [s], or ``None``."""
        if not self.needs_temperature:
            return None
        if self._temperature_problem is not None or self._temperature_time is None:
            return self._temperature_problem or "no temperature received yet"
        age = t - self._temperature_time
        timeout = self.config.temperature_timeout
        if timeout > 0.0 and age > timeout:
            return f"temperature estimate is stale ({age:.3g} s old, limit {timeout:.3g} s)"
        return None

    def command(self, z_ref: npt.ArrayLike, t: float) -> CommandResult:
        """Return the command for set points ``z_ref`` [m] (grid) at time ``t`` [s].

        Raises:
            FeedforwardInputError: ``z_ref`` does not have the grid's shape.

        """
        z = np.asarray(z_ref, np.float64)
        if z.shape != self.config.shape:
            raise FeedforwardInputError(
                f"set point grid is {z.shape}, expected {self.config.shape}"
            )
        problem = self.temperature_problem(t)
        if problem is not None:
            return CommandResult(
                self._last_voltage, self._last_status, True, problem, worst=self._last_worst
            )
        if self.needs_temperature:
            assert self._laws is not None and self._temperature is not None
            laws, T = self._laws, self._temperature
        else:
            laws, T = self._reference_laws, self._reference_T
        if self._plain_hyperbolic and self._fusable(laws, z):
            fused = fused_hyperbolic_inverse(laws, z, self.config.v_limit, SETPOINT_CEILING)
            if fused is not None:
                assert fused.worst is not None
                return self._keep(fused.voltage, fused.status, fused.worst)
        T_law = T
        for stage in self._stages.values():
            T_law = stage.law_temperature(T_law, t)
        if T_law is not T:
            T = T_law
            laws = self._laws_compiled.at(T)

        lo, hi = (z.min(), z.max()) if z.size else (0.0, 0.0)
        raw_status: StatusArray | None = None
        if not (lo >= 0.0 and hi <= SETPOINT_CEILING):  # NaN fails too
            raw_invalid = ~np.isfinite(z)
            raw_status = np.where(z < 0.0, CODE_CLIPPED_LOW, CODE_OK).astype(np.int8)
            raw_status[raw_invalid] = CODE_INVALID
            z = np.clip(np.where(raw_invalid, 0.0, z), 0.0, SETPOINT_CEILING)
        z = self._compensate_setpoint(z, T, t)

        model_error: FloatArray | None = None
        mode = self.config.mode
        v_limit = self.config.v_limit
        if mode is Mode.INVERSE_QUADRATIC:
            result = laws.quadratic_inverse(z, v_limit)
        elif mode is Mode.LINEARIZED_DMAX:
            result, model_error = self._linearized(laws, z)
        elif mode is Mode.OBSERVER:
            result, model_error = self._observer(laws, z)
        else:
            result = self._hyperbolic(laws, z)

        # the model inverses already return finite voltages in [0, v_limit]; only the
        # drive's inverses can leave that range
        voltage, status, worst = result.voltage, result.status, result.worst
        if self._drive_stages:
            voltage, status = self._drive_and_limits(result, t)
            worst = None  # the limits may have raised statuses
        if raw_status is not None:
            np.maximum(status, raw_status, out=status)
            self._observer_tanh = None
            worst = None
        if worst is None:
            worst = int(status.max()) if status.size else CODE_OK
        if worst >= CODE_INVALID:
            invalid = status == CODE_INVALID
            voltage[invalid] = self._last_voltage[invalid]
            if model_error is not None:
                model_error[invalid] = 0.0
        drive = voltage
        for stage in self._stages.values():
            drive = stage.commit(voltage, drive, t)
        return self._keep(voltage, status, worst, model_error)

    def _keep(
        self, voltage: FloatArray, status: StatusArray, worst: int,
        model_error: FloatArray | None = None,
    ) -> CommandResult:
        """Make this command the last good one and return it."""
        # shared with the caller without a copy: frozen so that nobody changes the state
        voltage.setflags(write=False)
        status.setflags(write=False)
        self._last_voltage = voltage
        self._last_status = status
        self._last_worst = worst
        return CommandResult(voltage, status, model_error=model_error, worst=worst)

    def _fusable(self, laws: LawsAtTemperature, z: FloatArray) -> bool:
        """Whether the fused kernels take these laws and set points (they flag no actuator)."""
        return self.backend is Backend.FUSED and not laws.flagged and z.size > 0

    def _hyperbolic(self, laws: LawsAtTemperature, z: FloatArray) -> InverseResult:
        """Return the hyperbolic inverse of ``z``, fused where the kernels and the laws allow."""
        v_limit = self.config.v_limit
        if self._fusable(laws, z):
            fused = fused_hyperbolic_inverse(laws, z, v_limit)
            if fused is not None:
                return fused
        return laws.hyperbolic_inverse(z, v_limit)

    def _compensate_setpoint(self, z: FloatArray, T: FloatArray, t: float) -> FloatArray:
        """Turn the wanted displacement into the wanted free (basic-model) displacement."""
        stages = self._stages.values()
        for stage in stages:
            z = stage.predict(z, t)
        # the forward chain undone from its end: the last stage's effect is removed first
        for stage in reversed(stages):
            z = stage.setpoint(z, T, t)
        return z

    def _reach_bounds(self, laws: LawsAtTemperature) -> tuple[float, FloatArray, FloatArray]:
        """Return set points [m] that ``v_limit`` surely reaches / surely does not reach.

        With z_reach = z(v_limit) (capped at RATIO_CAP z_sat) per actuator: (smallest
        z_reach (1 - REACH_MARGIN), z_reach (1 - REACH_MARGIN), z_reach (1 + REACH_MARGIN)),
        computed once per temperature. Only for laws that flag no actuator.
        """
        if self._reach is None or self._reach[0] is not laws:
            t = np.tanh(laws.q * self.config.v_limit)
            reach = np.minimum(t * t, RATIO_CAP) * laws.z_sat
            below = reach * (1.0 - REACH_MARGIN)
            self._reach = (laws, (float(below.min()), below, reach * (1.0 + REACH_MARGIN)))
        return self._reach[1]

    def _reach_status(self, laws: LawsAtTemperature, z: FloatArray) -> StatusArray:
        """Return the hyperbolic inverse's status of ``z`` without inverting where it is clear.

        Usable laws and finite z >= 0 away from the reach of ``v_limit``: OK below it,
        CLIPPED_HIGH beyond; anything else (set points within REACH_MARGIN of the reach
        included) takes the inverse itself.
        """
        if not laws.flagged and z.size and z.min() >= 0.0:
            everywhere, below, beyond = self._reach_bounds(laws)
            if z.max() < everywhere:
                return np.zeros(z.shape, np.int8)
            high = z >= beyond
            if np.count_nonzero(high) == z.size - np.count_nonzero(z < below):
                return high.astype(np.int8) * np.int8(CODE_CLIPPED_HIGH)
        return laws.hyperbolic_inverse(z, self.config.v_limit).status

    @staticmethod
    def _model_error(laws: LawsAtTemperature, voltage: FloatArray, z: FloatArray) -> FloatArray:
        """Return z_model(voltage) - z [m] (``laws.hyperbolic_forward``, in one buffer)."""
        error = np.multiply(laws.q, voltage)
        np.tanh(error, out=error)
        error *= error
        error /= laws.inv_zsat
        error -= z
        return error

    def _linearized(
        self, laws: LawsAtTemperature, z: FloatArray
    ) -> tuple[InverseResult, FloatArray]:
        """Bias at V_max(T), drive z - z_sat/3 through 1 / d_max(T)."""
        v_limit = self.config.v_limit
        if self._fusable(laws, z):
            _, below, beyond = self._reach_bounds(laws)
            fused = fused_linearized(laws, z, below, beyond, v_limit)
            if fused is not None:
                return fused
        voltage = np.maximum(z, 0.0)
        voltage /= laws.d_max
        voltage += laws.linear_offset
        if voltage.size and not (voltage.min() >= 0.0 and voltage.max() <= v_limit):
            np.clip(voltage, 0.0, v_limit, out=voltage)
        status = self._reach_status(laws, z)  # statuses of the set point
        if status.size and status.max() >= CODE_CLIPPED_HIGH:
            voltage[status == CODE_CLIPPED_HIGH] = v_limit
        error = self._model_error(laws, voltage, z)
        return limit_voltages(voltage, status, v_limit), error

    def _observer(self, laws: LawsAtTemperature, z: FloatArray) -> tuple[InverseResult, FloatArray]:
        """Run the observer's PI loop towards z; the integrator state persists.

        The loop works on y = sqrt(z) (linear in V at low field: y = sqrt(M/L) V) and its
        gain is scheduled on the observer's local gain dy/dV = sqrt(M/L) sech^2(k V / L),
        so with kp + ki <= 1 it approaches the set point from below without overshoot
        (:func:`es_feedforward.kernels.observer_command`).
        """
        gains = self.config.observer
        v_limit = self.config.v_limit
        known = self._observer_tanh
        out = observer_command(
            self._integral, laws, z, v_limit=v_limit, kp=gains.kp, ki=gains.ki,
            iterations=gains.iterations, tolerance=gains.tolerance, backend=self.backend,
            tanh_of_integral=known[2] if known and known[0] is laws and known[1] is self._integral
            else None,
        )  # fmt: skip
        self._integral = out.integral
        status = None
        if self._fusable(laws, z):
            _, below, beyond = self._reach_bounds(laws)
            status = fused_reach_status(z, out.voltage, below, beyond, v_limit)
        # tanh(q I) starts the next set point's loop only if nothing changes I in place
        # (limit_voltages zeroes CLIPPED_LOW/INVALID; command substitutes invalid ones)
        reusable = gains.kp == 0.0 and not self._stages and not laws.flagged
        if status is None:
            status = self._reach_status(laws, z)
            result = limit_voltages(out.voltage, status, v_limit)
            worst = int(status.max()) if status.size else CODE_OK
            if worst >= CODE_CLIPPED_LOW:
                reusable = (
                    reusable and worst < CODE_INVALID and not np.any(status == CODE_CLIPPED_LOW)
                )
        else:  # the fused statuses are OK or CLIPPED_HIGH only
            result = InverseResult(out.voltage, status)
        self._observer_tanh = (laws, out.integral, out.tanh_of_voltage) if reusable else None
        return result, out.model_error

    def _drive_and_limits(
        self, result: InverseResult, t: float
    ) -> tuple[FloatArray, StatusArray]:
        """Undo the drive's stages (last first), then keep every voltage in [0, v_limit]."""
        status = result.status
        voltage = result.voltage
        for stage in reversed(self._drive_stages):
            voltage = stage.invert_drive(voltage, t)
        v_limit = self.config.v_limit
        if voltage.size and not (voltage.min() >= 0.0 and voltage.max() <= v_limit):
            bad = ~np.isfinite(voltage)
            status[bad] = CODE_INVALID
            voltage = np.where(bad, self._last_voltage, voltage)
            status[(voltage > v_limit) & (status < CODE_CLIPPED_HIGH)] = CODE_CLIPPED_HIGH
            status[(voltage < 0.0) & (status < CODE_CLIPPED_LOW)] = CODE_CLIPPED_LOW
            voltage = np.clip(voltage, 0.0, v_limit)
        return voltage, status
