"""Effects beyond the basic law, one module each, found through :mod:`.registry`.

Public face: :class:`Effect`, :class:`Parameter`, :class:`Role`, :class:`FittedEffect`,
:class:`Additive`, the errors, and the registry's :func:`registry`, :func:`get`,
:func:`names`, :func:`candidates`, :func:`with_role`, :func:`in_model_order`; the stages
(:class:`PlantStage`, :class:`Compensator` and what their hooks see).
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
    in_model_order,
    names,
    registry,
    with_role,
)
from es_physics.effects.stages import (
    Compensator,
    Drive,
    PlantContext,
    PlantStage,
    StepState,
)
from es_physics.errors import EffectError, UnknownEffectError

__all__ = [
    "ENTRY_POINT_GROUP",
    "Additive",
    "Compensator",
    "Drive",
    "Effect",
    "EffectError",
    "FittedEffect",
    "Parameter",
    "PlantContext",
    "PlantStage",
    "Role",
    "StepState",
    "UnknownEffectError",
    "candidates",
    "get",
    "in_model_order",
    "names",
    "registry",
    "with_role",
]
