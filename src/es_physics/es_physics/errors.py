"""The exception classes of es_physics, in one place (pure: no imports at all).

Every class subclasses ``ValueError``, so a generic handler still catches them, while a
caller that wants "an effect problem" catches just that.

- :class:`EffectError`: an effect definition or an effect setting is invalid
  (:mod:`es_physics.effects`).
- :class:`UnknownEffectError`: a name that no registered effect has.
- :class:`EffectParameterError`: an effect's parameter is out of its range (a corner
  frequency <= 0, a negative gain).
"""

from __future__ import annotations

__all__ = ["EffectError", "EffectParameterError", "UnknownEffectError"]


class EffectError(ValueError):
    """An effect definition or an effect setting is invalid."""


class UnknownEffectError(EffectError):
    """A name that no registered effect has."""


class EffectParameterError(EffectError):
    """An effect's parameter is outside its range; the message names it and the bound."""
