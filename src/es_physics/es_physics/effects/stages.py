"""Where an effect acts: its stage in the simulator and its stage in the feedforward.

An :class:`~es_physics.effects.base.Effect` builds, from its settings, a
:class:`PlantStage` (:meth:`Effect.plant_stage`, the forward model the simulator applies)
and a :class:`Compensator` (:meth:`Effect.compensator`, what the feedforward does against
it). The simulator and the feedforward never name an effect: they build one stage per
enabled effect, in :func:`es_physics.effects.registry.in_model_order`, and call every
stage's hooks in that order (the drive inverses in the reverse order). Every hook defaults
to doing nothing, so a stage overrides only the hooks where its effect acts.

Simulator hooks, in the order of one plant step (see ``es_sim_plant.actuators``):
:meth:`PlantStage.law` (the actuators' law coefficients, once),
:meth:`PlantStage.sensor_lag_s` (the temperature sensor's lag, once),
:meth:`PlantStage.transport_steps` (the command's delay, once),
:meth:`PlantStage.heating` (actuator heat from the applied drive),
:meth:`PlantStage.drive` (the voltage in effect), :meth:`PlantStage.displacement` (the
displacement after the law).

Feedforward hooks, in the order of one command (see ``es_feedforward.feedforward``):
:meth:`Compensator.measured_temperature` (each temperature estimate),
:meth:`Compensator.law_temperature` (the temperature the law is evaluated at),
:meth:`Compensator.predict` (the wanted displacement in time, e.g. ahead over a delay),
:meth:`Compensator.setpoint` (the wanted displacement -> the basic model's; in reverse model
order: the forward chain undone from its end),
:meth:`Compensator.invert_drive` (the law's voltage -> the command; only when
:attr:`Compensator.reshapes_drive`), :meth:`Compensator.commit` (the command sent).
"""

from __future__ import annotations

from dataclasses import dataclass

from es_common.arrays import BoolArray, FloatArray
from es_physics.params import ActuatorParams


@dataclass(frozen=True)
class PlantContext:
    """What a plant stage is built for.

    Attributes:
        shape: grid (R, C).
        dt: plant (control) step [s].
        substeps: internal steps per plant step (>= 1).
        reference_temperature: the run's initial base temperature [degC].

    """

    shape: tuple[int, int]
    dt: float
    substeps: int
    reference_temperature: float


@dataclass(frozen=True)
class Drive:
    """The applied (delayed, saturated) commands of one plant step, each (R, C) [V].

    Attributes:
        previous: the command in force before the step's switch.
        current: the command in force after it.
        before: the voltage applied before the switch (``current`` when the switch is at 0).
        after: the voltage applied after it (= ``current``).

    """

    previous: FloatArray
    current: FloatArray
    before: FloatArray
    after: FloatArray


@dataclass(frozen=True)
class StepState:
    """One plant step as the response hooks see it; m evaluated internal steps.

    Attributes:
        drive: the applied commands.
        T: actuator temperatures at the ends of the evaluated internal steps (m, R, C) [degC].
        times: run time at those ends (m,) [s].
        before_switch: which of them lie before the drive's switch (m, 1, 1).
        params: the actuators' per-actuator law coefficients.
        reference_temperature: the run's initial base temperature [degC].

    """

    drive: Drive
    T: FloatArray
    times: FloatArray
    before_switch: BoolArray
    params: ActuatorParams
    reference_temperature: float


class PlantStage:
    """An enabled effect's part of the simulator; every hook is a no-op by default."""

    #: The stage must see every internal step (a filter in time), not only the step's end.
    every_substep: bool = False

    def law(self, params: ActuatorParams) -> ActuatorParams:
        """Return the nominal law coefficients the actuators really have."""
        return params

    def sensor_lag_s(self) -> float | None:
        """Return the temperature sensor's first-order lag [s], or None."""
        return None

    def transport_steps(self) -> int:
        """Return the command's delay in internal steps (>= 0)."""
        return 0

    def heating(self, drive: Drive) -> FloatArray | None:
        """Return the actuators' heat input over the step [W] (R, C), or None."""
        return None

    def drive(self, voltage: FloatArray, step: StepState) -> FloatArray:
        """Return the voltage in effect [V] for the applied ``voltage`` (m or 1, R, C)."""
        return voltage

    def displacement(self, z: FloatArray, step: StepState) -> FloatArray:
        """Return the displacement [m] (m, R, C) after this stage, from the one before it."""
        return z


class Compensator:
    """An effect's compensation in the feedforward; every hook is a no-op by default.

    A compensator holds the state of its compensation for one grid; the feedforward
    builds a new one on every reconfiguration (:meth:`Effect.compensator` gets the old one
    to carry its state over).
    """

    #: :meth:`invert_drive` changes the voltage (the command then needs its limits again).
    reshapes_drive: bool = False

    def measured_temperature(self, T: FloatArray, t: float) -> FloatArray:
        """Return the actuator temperatures [degC] for an estimate ``T`` taken at ``t`` [s]."""
        return T

    def law_temperature(self, T: FloatArray, t: float) -> FloatArray:
        """Return the temperatures [degC] the law is evaluated at for a command at ``t``."""
        return T

    def predict(self, z: FloatArray, t: float) -> FloatArray:
        """Return the wanted displacement [m] to aim at for the set point ``z`` given at ``t``."""
        return z

    def setpoint(self, z: FloatArray, T: FloatArray, t: float) -> FloatArray:
        """Return the displacement [m] the stages before this one must produce for ``z``."""
        return z

    def invert_drive(self, voltage: FloatArray, t: float) -> FloatArray:
        """Return the drive [V] that makes this stage output ``voltage`` (command at ``t``)."""
        return voltage

    def counters(self) -> dict[str, int]:
        """Return counts of commands this stage could not compensate fully, by name."""
        return {}

    def commit(self, sent: FloatArray, drive: FloatArray, t: float) -> FloatArray:
        """Advance the state with the command ``sent`` [V] at ``t`` [s].

        ``drive`` is the voltage in effect after the drive stages before this one; the
        return value is this stage's output, the next drive stage's input.
        """
        return drive
