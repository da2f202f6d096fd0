"""Effects beyond the basic law, one module each, found through :mod:`.registry`.

Public face: :class:`Effect`, :class:`Parameter`, :class:`Role`, :class:`FittedEffect`,
:class:`Additive`, the errors, and the registry's :func:`registry`, :func:`get`,
:func:`names`, :func:`candidates`, :func:`with_role`.
"""

from es_physics.effects.base import (
    Additive,
    Effect,
    FittedEffect,
    Parameter,
    Role,
)
from es_physics.effects.registry import (
    ENTRY_POINT_GROUP,
    candidates,
    get,
    names,
    registry,
    with_role,
)
from es_physics.errors import EffectError, UnknownEffectError

__all__ = [
    "ENTRY_POINT_GROUP",
    "Additive",
    "Effect",
    "EffectError",
    "FittedEffect",
    "Parameter",
    "Role",
    "UnknownEffectError",
    "candidates",
    "get",
    "names",
    "registry",
    "with_role",
]
