"""The plant core: a whole deformable mirror stepped at the control rate, and an offline runner.

:class:`Plant` composes the thermal network, the sensors, the actuator grid and the scenario's
reference signals; it is pure numpy (no rclpy), deterministic for a given scenario seed, and
the node (:mod:`es_sim_plant.plant_node`) is a thin wrapper around it. :func:`simulate` runs
a whole scenario offline against a controller callback or a command array and returns every
time series (see docs/architecture.md, "Plant core API").

Timing convention (the same in the node): step k covers [t_k, t_k+1), t_k = k / control_rate.
At t_k the plant offers the set point r(t_k), the sensor sample (every
:func:`sensor_every` steps, starting at k = 0) and the heat load of the
coming step; the command u_k is held over the step; the displacement at the end of the step,
z(t_k+1), is the response to u_k at the temperatures of t_k+1.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from es_common.arrays import FloatArray, IntArray
from es_physics.params import ActuatorParams
from es_sim_plant.actuators import ActuatorGrid
from es_sim_plant.errors import CommandError, SimulationInputError
from es_sim_plant.reference import ExcitationGenerator, SetpointGenerator
from es_sim_plant.resonance import ResonanceSensor
from es_sim_plant.scenario import Scenario
from es_sim_plant.sensors import SensorArray
from es_sim_plant.thermal import ThermalNetwork


def sensor_every(control_rate: float, sensor_rate: float) -> int:
    """Return after how many control steps the plant takes a sensor sample (at least 1)."""
    return max(1, round(control_rate / sensor_rate))


#: Seed streams, one per random consumer, so switching one on leaves the others unchanged.
_STREAMS = (
    "spread", "sensor_offsets", "sensor_noise", "displacement_noise", "excitation",
    "resonance_spread", "resonance_noise",
)  # fmt: skip


class Plant:
    """One simulated mirror; call :meth:`step` once per control period.

    Args:
        scenario: what to simulate (time already scaled; see :mod:`es_sim_plant.scenario`).

    Raises:
        ScenarioError: the scenario does not fit together (e.g. sensor positions off the grid).

    """

    def __init__(self, scenario: Scenario) -> None:
        scenario.validate()
        self.scenario = scenario
        self.shape: tuple[int, int] = scenario.shape
        self.dt = 1.0 / scenario.control_rate
        #: Number of control steps of the whole scenario.
        self.steps = max(1, round(scenario.duration * scenario.control_rate))
        #: A sensor sample is taken every ``sensor_every`` steps (k = 0, n, 2n, ...).
        self.sensor_every = sensor_every(scenario.control_rate, scenario.sensor_rate)
        # spawn(n) gives the same first children for any n: a new stream changes no old one
        children = np.random.SeedSequence(scenario.seed).spawn(len(_STREAMS))
        rngs = dict(zip(_STREAMS, (np.random.default_rng(s) for s in children), strict=True))
        self._displacement_rng = rngs["displacement_noise"]
        t0 = scenario.initial_base_temperature
        self.thermal = ThermalNetwork(self.shape, scenario.thermal, self.dt, t0)
        self.actuators = ActuatorGrid(
            self.shape,
            config=scenario.actuators,
            effects=scenario.effects,
            dt=self.dt,
            reference_temperature=t0,
            rng=rngs["spread"],
        )
        self.sensors = SensorArray(
            self.shape,
            config=scenario.sensors,
            lag_tau=self.actuators.sensor_lag_s,
            dt=self.dt,
            initial_temperature=t0,
            rng_offsets=rngs["sensor_offsets"],
            rng_noise=rngs["sensor_noise"],
        )
        self.setpoints = SetpointGenerator(scenario.setpoint, self.shape)
        self.excitation = (
            None
            if scenario.excitation is None
            else ExcitationGenerator(
                scenario.excitation, self.shape, scenario.actuators.v_limit, rngs["excitation"]
            )
        )
        self._power_map = (
            np.zeros(self.shape)
            if scenario.illumination is None
            else scenario.illumination.power_map(self.shape)
        )
        #: The self-sensing resonance sweeps (None unless the scenario switches them on).
        self.resonance = (
            ResonanceSensor(
                self.shape, scenario.resonance, rngs["resonance_spread"], rngs["resonance_noise"]
            )
            if scenario.resonance.enabled
            else None
        )
        self.k = 0
        self._displacement = np.zeros(self.shape)

    # --- what the plant offers at t_k -------------------------------------------------------
    @property
    def time(self) -> float:
        """t_k = k / control_rate [s]."""
        return self.k * self.dt

    @property
    def done(self) -> bool:
        """True once all :attr:`steps` of the scenario were taken."""
        return self.k >= self.steps

    @property
    def sensor_count(self) -> int:
        """Number of temperature sensors S."""
        return self.sensors.count

    @property
    def v_limit(self) -> float:
        """Amplifier limit [V]."""
        return self.scenario.actuators.v_limit

    @property
    def true_params(self) -> ActuatorParams:
        """The per-actuator parameters the simulated actuators really have (maps of shape)."""
        return self.actuators.params

    def sensor_due(self) -> bool:
        """Tell whether a temperature sample (and heat-load message) belongs to step k."""
        return self.k % self.sensor_every == 0

    def setpoint(self) -> FloatArray:
        """Scenario set point r(t_k) (R, C) [m]."""
        return self.setpoints.at(self.time)

    def excitation_command(self) -> FloatArray | None:
        """Test-stand voltage program at t_k (R, C) [V], or ``None`` without an excitation."""
        return None if self.excitation is None else self.excitation.at(self.time)

    def heat_load(self) -> FloatArray:
        """Absorbed UV power per cell (R, C) [W], mean over the step [t_k, t_k+1)."""
        if self.scenario.illumination is None:
            return np.zeros(self.shape)
        on = self.scenario.schedule.on_fraction(self.time, self.time + self.dt)
        return self._power_map * on

    def base_temperature(self) -> float:
        """Base-plate temperature T_b(t_k) [degC]."""
        return self.scenario.base.at(self.time)

    def actuator_temperature(self) -> FloatArray:
        """Return the true actuator temperatures at t_k (R, C) [degC] (read-only)."""
        return self.thermal.actuator_temperatures()

    def face_temperature(self) -> FloatArray:
        """Return the true face-sheet temperatures at t_k (R, C) [degC] (read-only)."""
        return self.thermal.temperatures()[0]

    def read_sensors(self) -> FloatArray:
        """Take one sensor sample at t_k (S,) [degC]; draws noise (call once per due step)."""
        return self.sensors.read()

    def read_resonance(self) -> FloatArray | None:
        """Sweep the next group at t_k under the command in force; (R, C) [Hz], NaN unswept.

        ``None`` when the scenario has no resonance measurement. Call once per due sensor
        step, like :meth:`read_sensors`.
        """
        if self.resonance is None:
            return None
        return self.resonance.measure(self.actuator_temperature(), self.actuators.command)

    def displacement(self) -> FloatArray:
        """Return the true displacement at t_k (R, C) [m], the response to the previous command."""
        return self._displacement

    def measured_displacement(self) -> FloatArray:
        """Return the truth at t_k plus interferometer noise (``displacement_noise`` m rms)."""
        sd = self.scenario.displacement_noise
        if sd <= 0.0:
            return self._displacement
        return self._displacement + sd * self._displacement_rng.standard_normal(self.shape)

    def check_command(self, command: npt.ArrayLike) -> str | None:
        """Return why ``command`` may not reach the actuators, or ``None`` when it may.

        Rejected: wrong shape, non-finite values, values beyond the amplifier limit.
        """
        arr = np.asarray(command, np.float64)
        if arr.shape != self.shape:
            return f"command shape {arr.shape} != grid {self.shape}"
        finite = np.isfinite(arr)
        if not finite.all():
            return f"{int(np.count_nonzero(~finite))} non-finite value(s)"
        worst = float(np.max(np.abs(arr)))
        if worst > self.v_limit:
            return f"|V| up to {worst:.6g} V beyond the amplifier limit {self.v_limit:g} V"
        return None

    # --- advancing ------------------------------------------------------------------------
    def step(self, command: npt.ArrayLike, all_substeps: bool = False) -> FloatArray:
        """Apply ``command`` (R, C) [V] over [t_k, t_k+1) and advance to k + 1.

        Values beyond the amplifier limit saturate (as a real amplifier would); callers that
        must reject them use :meth:`check_command` first.

        Returns:
            The displacements [m] at the ends of the internal steps, (substeps, R, C) with
            ``all_substeps``, else (1, R, C) holding z(t_k+1).

        Raises:
            CommandError: wrong shape or non-finite values.

        """
        cmd = np.asarray(command, np.float64)
        if cmd.shape != self.shape or not np.isfinite(cmd).all():
            raise CommandError(f"invalid command: {self.check_command(cmd)}")
        t0 = self.time
        self.actuators.apply(cmd)
        heat = self.heat_load()
        actuator_heat = self.actuators.heating_power
        T_start = self.thermal.actuator_temperatures()
        self.thermal.step(heat, actuator_heat, self.scenario.base.mean(t0, t0 + self.dt))
        T_end = self.thermal.actuator_temperatures()
        z = self.actuators.respond(T_start, T_end, t0, all_substeps)
        self._displacement = z[-1]
        self.sensors.track(T_end)
        self.k += 1
        return z


@dataclass(frozen=True)
class Observation:
    """What a controller sees at step k (what the node publishes before waiting).

    ``temperature_raw`` and ``heat_load`` are ``None`` on steps without a sensor sample;
    ``resonance`` (R, C) [Hz], NaN where not swept, only comes with a sensor sample of a
    scenario with the resonance measurement on.
    """

    step: int
    time: float
    setpoint: FloatArray
    temperature_raw: FloatArray | None
    heat_load: FloatArray | None
    resonance: FloatArray | None = None


#: A controller maps the observation of step k to the command (R, C) [V] for that step.
Controller = Callable[[Observation], npt.ArrayLike]


@dataclass(frozen=True)
class SimulationResult:
    """Time series of one offline run; K steps, S sensors, Ns sensor samples, n substeps.

    Attributes:
        scenario: the scenario that ran (time-scaled).
        true_params: the per-actuator parameters of the simulated actuators (maps (R, C)).
        time: t_k (K,) [s].
        setpoint: r(t_k) (K, R, C) [m].
        command: command applied over step k after amplifier saturation (K, R, C) [V].
        actuator_temperature: true T_a(t_k) (K, R, C) [degC].
        face_temperature: true face-sheet T_f(t_k) (K, R, C) [degC].
        base_temperature: T_b(t_k) (K,) [degC].
        heat_load: absorbed UV power, mean over step k (K, R, C) [W].
        displacement: true z at the END of step k, t_k+1, response to command[k] (K, R, C) [m].
        displacement_measured: ``displacement`` + interferometer noise (K, R, C) [m].
        sensor_step: step index of each sensor sample (Ns,).
        sensor_time: t of each sample (Ns,) [s].
        temperature_raw: the sensor samples (Ns, S) [degC].
        resonance: the resonance readings at the sensor samples (Ns, R, C) [Hz], or ``None``
            when the scenario has no resonance measurement.
        substep_time: end time of every internal step (K n,) [s], or ``None``.
        substep_displacement: true z at those times (K n, R, C) [m], or ``None``.

    """

    scenario: Scenario
    true_params: ActuatorParams
    time: FloatArray
    setpoint: FloatArray
    command: FloatArray
    actuator_temperature: FloatArray
    face_temperature: FloatArray
    base_temperature: FloatArray
    heat_load: FloatArray
    displacement: FloatArray
    displacement_measured: FloatArray
    sensor_step: IntArray
    sensor_time: FloatArray
    temperature_raw: FloatArray
    substep_time: FloatArray | None = None
    substep_displacement: FloatArray | None = None
    resonance: FloatArray | None = None


def simulate(
    plant: Plant,
    controller: Controller | None = None,
    commands: npt.ArrayLike | None = None,
    steps: int | None = None,
    record_substeps: bool = False,
) -> SimulationResult:
    """Run ``plant`` from its current step and return every time series.

    The command of step k comes from ``controller(observation_k)``, else ``commands[k]``
    (anything broadcasting to (K, R, C); K >= steps), else the scenario's excitation.
    Controller outputs beyond the amplifier limit saturate; NaN or a wrong shape raise.

    Args:
        plant: a fresh (or partly run) plant.
        controller: callback giving the command of each step.
        commands: pre-computed commands [V].
        steps: how many steps to run (default: to the end of the scenario).
        record_substeps: also return the displacement at every internal step.

    Raises:
        SimulationInputError: no command source, or a command of wrong shape or with NaN.

    """
    count = plant.steps - plant.k if steps is None else int(steps)
    shape = plant.shape
    cmd_array: FloatArray | None = None
    if controller is None and commands is not None:
        raw = np.asarray(commands, np.float64)
        if raw.ndim == 1:
            raw = raw[:, None, None]
        if raw.shape[0] < count:
            raise SimulationInputError(f"commands has {raw.shape[0]} steps, {count} needed")
        cmd_array = np.broadcast_to(raw[:count], (count, *shape))
    elif controller is None and plant.excitation is None:
        raise SimulationInputError(
            "simulate needs a controller, a command array or a scenario excitation"
        )
    n = plant.actuators.substeps
    out = {
        name: np.empty((count, *shape))
        for name in (
            "setpoint", "command", "actuator_temperature", "face_temperature", "heat_load",
            "displacement", "displacement_measured",
        )
    }  # fmt: skip
    time = np.empty(count)
    base = np.empty(count)
    sensor_steps: list[int] = []
    readings: list[FloatArray] = []
    resonance: list[FloatArray] = []
    sub = np.empty((count * n, *shape)) if record_substeps else None
    for i in range(count):
        k = plant.k
        time[i] = plant.time
        r = plant.setpoint()
        heat = plant.heat_load()
        raw_temperature: FloatArray | None = None
        swept: FloatArray | None = None
        if plant.sensor_due():
            raw_temperature = plant.read_sensors()
            sensor_steps.append(k)
            readings.append(raw_temperature)
            swept = plant.read_resonance()
            if swept is not None:
                resonance.append(swept)
        if controller is not None:
            observation = Observation(
                k,
                plant.time,
                r,
                raw_temperature,
                heat if raw_temperature is not None else None,
                swept,
            )
            command = np.asarray(controller(observation), np.float64)
        elif cmd_array is not None:
            command = cmd_array[i]
        else:
            command = plant.excitation_command()  # type: ignore[assignment]
        out["setpoint"][i] = r
        out["heat_load"][i] = heat
        out["actuator_temperature"][i] = plant.actuator_temperature()
        out["face_temperature"][i] = plant.face_temperature()
        base[i] = plant.base_temperature()
        z = plant.step(command, all_substeps=record_substeps)
        out["command"][i] = plant.actuators.command
        out["displacement"][i] = z[-1]
        out["displacement_measured"][i] = plant.measured_displacement()
        if sub is not None:
            sub[i * n : (i + 1) * n] = z
    sensor_step = np.asarray(sensor_steps, np.int64)
    return SimulationResult(
        scenario=plant.scenario,
        true_params=plant.true_params,
        time=time,
        base_temperature=base,
        sensor_step=sensor_step,
        sensor_time=np.asarray(sensor_step * plant.dt, np.float64),
        temperature_raw=(np.asarray(readings) if readings else np.empty((0, plant.sensor_count))),
        substep_time=(
            None if sub is None else time[0] + plant.dt / n * np.arange(1, count * n + 1)
        ),
        substep_displacement=sub,
        resonance=(
            None if plant.resonance is None else np.asarray(resonance).reshape(-1, *shape)
        ),
        **out,
    )
