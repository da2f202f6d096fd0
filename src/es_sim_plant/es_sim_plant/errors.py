"""The exception classes of es_sim_plant's simulator, in one place (pure: no imports at all).

Every class subclasses ``ValueError``, so a generic handler still catches them, while a
caller that wants "a scenario problem" catches just that.

- :class:`ScenarioError`: a scenario (file, section or override) is missing, malformed or
  out of range (:mod:`es_sim_plant.scenario` and the sections it reads: thermal,
  illumination, base temperature, sensors, actuators, set point, excitation, resonance).
- :class:`CommandError`: a command given to the plant is not applicable (wrong shape,
  non-finite, beyond the amplifier limit).
- :class:`SimulationInputError`: an offline run was asked for something it cannot do (no
  command source, too few commands, an unknown study case).
"""

from __future__ import annotations

__all__ = ["CommandError", "ScenarioError", "SimulationInputError"]


class ScenarioError(ValueError):
    """A scenario or one of its sections is missing, malformed or out of range."""


class CommandError(ValueError):
    """A command [V, grid] the plant cannot apply; the message gives the reason."""


class SimulationInputError(ValueError):
    """An offline simulation lacks what it needs or names an unknown case."""
