"""The effect registry: built-in effect modules plus the entry-point group ``es_dm.effects``.

An external package adds an effect by declaring, in its packaging metadata::

    [project.entry-points."es_dm.effects"]
    my_effect = "my_package.my_module:MyEffect"

where ``MyEffect`` subclasses :class:`es_physics.effects.base.Effect`. The registry is read
once per process (:func:`registry`); built-in names cannot be replaced.
"""

from __future__ import annotations

from functools import cache
from importlib.metadata import entry_points
from typing import Final

from es_physics.effects.base import Effect, Role
from es_physics.effects.coupling import Coupling
from es_physics.effects.delay import Delay
from es_physics.effects.discovered import Discovered
from es_physics.effects.drift import Drift
from es_physics.effects.frequency_dispersion import FrequencyDispersion
from es_physics.effects.hysteresis import Hysteresis
from es_physics.effects.self_heating import SelfHeating
from es_physics.effects.sensor_lag import SensorLag
from es_physics.effects.temperature_curvature import TemperatureCurvature
from es_physics.effects.thermal_expansion import ThermalExpansion
from es_physics.errors import EffectError, UnknownEffectError

#: Entry-point group through which other packages add effects.
ENTRY_POINT_GROUP: Final = "es_dm.effects"

#: Built-in effects, in the order of docs/architecture.md's table.
BUILT_IN: Final[tuple[type[Effect], ...]] = (
    SensorLag,
    Delay,
    Hysteresis,
    Coupling,
    ThermalExpansion,
    Drift,
    TemperatureCurvature,
    SelfHeating,
    FrequencyDispersion,
    Discovered,
)


def _checked(effect: Effect) -> Effect:
    """Return ``effect`` after checking its declarations; raise :class:`EffectError`."""
    if not effect.name.isidentifier():
        raise EffectError(f"effect name {effect.name!r} is not an identifier")
    for p in effect.plant:
        p.check(p.default, f"effects.{effect.name}")
    if effect.simulated and type(effect).plant_stage is Effect.plant_stage:
        raise EffectError(f"effect {effect.name} is simulated but has no plant_stage")
    if effect.role is Role.ADDITIVE and effect.local_parameters:
        raise EffectError(f"additive effect {effect.name} cannot have per-actuator unknowns")
    return effect


@cache
def registry() -> dict[str, Effect]:
    """Return every effect by canonical name: built-ins first, then entry points.

    Raises:
        EffectError: an entry point that does not load, is no :class:`Effect` subclass,
            reuses a registered name, or a second effect claims a single-effect role.

    """
    found: dict[str, Effect] = {}
    classes: list[tuple[str, object]] = [(cls.__name__, cls) for cls in BUILT_IN]
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        try:
            classes.append((f"entry point {ep.name} = {ep.value}", ep.load()))
        except Exception as exc:  # an external package's import failure, any kind
            raise EffectError(f"{ENTRY_POINT_GROUP}: entry point {ep.name} fails: {exc}") from exc
    roles: dict[Role, str] = {}
    for origin, cls in classes:
        if not (isinstance(cls, type) and issubclass(cls, Effect)):
            raise EffectError(f"{origin} is not an es_physics Effect class")
        effect = _checked(cls())
        if effect.name in found:
            raise EffectError(f"{origin}: effect {effect.name!r} is already registered")
        single = effect.role not in (Role.ADDITIVE, Role.PLANT_ONLY)
        if single and effect.role in roles:
            raise EffectError(
                f"{origin}: role {effect.role.value} already taken by {roles[effect.role]}"
            )
        roles[effect.role] = effect.name
        found[effect.name] = effect
    return found


def names() -> tuple[str, ...]:
    """Return every registered effect name, in registry order."""
    return tuple(registry())


def candidates() -> tuple[str, ...]:
    """Return the names of the effects the calibration may add, in registry order."""
    return tuple(n for n, e in registry().items() if e.candidate)


def get(name: str) -> Effect:
    """Return the effect called ``name``.

    Raises:
        UnknownEffectError: no registered effect has that name.

    """
    try:
        return registry()[name]
    except KeyError:
        raise UnknownEffectError(
            f"unknown effect {name!r}; known: {', '.join(registry())}"
        ) from None


def with_role(role: Role, among: tuple[str, ...] | None = None) -> Effect | None:
    """Return the effect of a single-effect ``role`` (among the names given), or None."""
    for name, effect in registry().items():
        if effect.role is role and (among is None or name in among):
            return effect
    return None


def in_model_order(among: tuple[str, ...] | list[str] | None = None) -> list[Effect]:
    """Return the effects (all, or those named), sorted by :class:`Role` then registry order.

    The order in which the simulator and the feedforward chain the effects' stages.

    Raises:
        UnknownEffectError: a name that no registered effect has.

    """
    order = list(Role)
    chosen = registry().values() if among is None else [get(n) for n in among]
    index = {name: i for i, name in enumerate(registry())}
    return sorted(chosen, key=lambda e: (order.index(e.role), index[e.name]))
