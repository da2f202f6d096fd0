"""The simulator's switches and parameters of the effects beyond the basic model.

Which effects exist, their parameters, ranges, defaults and which are slow times that a
scenario's ``time_scale`` multiplies all come from the effect registry
(:mod:`es_physics.effects`); this module only holds the settings a scenario or a node
parameter gives (``effects.<name>.enabled``, ``effects.<name>.<param>``). Every effect is off
by default. The forward models live with each effect's definition in es_physics; this
module builds their stages (:meth:`Effects.stages`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Final

from es_physics.effects import EffectError, PlantContext, PlantStage, in_model_order, registry

#: Canonical names of the effects the simulator implements, in registry order.
EFFECT_NAMES: Final = tuple(name for name, e in registry().items() if e.simulated)


@dataclass(frozen=True)
class EffectSettings:
    """One effect's switch and its parameters' values (attribute access by parameter name).

    Attributes:
        name: the effect's canonical name.
        enabled: whether the simulator applies it.
        values: (parameter name, value) pairs in the effect's declaration order (SI units).

    """

    name: str
    enabled: bool
    values: tuple[tuple[str, float], ...]

    def __getattr__(self, key: str) -> float:
        """Return the value of parameter ``key``.

        Raises:
            AttributeError: the effect has no such parameter.

        """
        if key.startswith("__") or key in ("name", "enabled", "values"):
            raise AttributeError(key)
        for name, value in self.values:
            if name == key:
                return value
        raise AttributeError(f"effect {self.name} has no parameter {key!r}")

    def with_values(self, **changes: float) -> EffectSettings:
        """Return a copy with some parameter values replaced (no range check)."""
        return replace(self, values=tuple((k, changes.get(k, v)) for k, v in self.values))


def _defaults(name: str) -> EffectSettings:
    return EffectSettings(name, False, tuple((p.name, p.default) for p in registry()[name].plant))


def _all_defaults() -> tuple[EffectSettings, ...]:
    return tuple(_defaults(name) for name in EFFECT_NAMES)


@dataclass(frozen=True)
class Effects:
    """Switches and parameters of every simulated effect (all off by default).

    ``effects.<name>`` is that effect's :class:`EffectSettings`.
    """

    settings: tuple[EffectSettings, ...] = field(default_factory=_all_defaults)

    def __getattr__(self, name: str) -> EffectSettings:
        """Return the settings of effect ``name``.

        Raises:
            AttributeError: no simulated effect has that name.

        """
        if name.startswith("__") or name == "settings":
            raise AttributeError(name)
        for s in self.settings:
            if s.name == name:
                return s
        raise AttributeError(f"no simulated effect {name!r}; known: {list(EFFECT_NAMES)}")

    def enabled_names(self) -> list[str]:
        """Return the canonical names of the effects that are on."""
        return [s.name for s in self.settings if s.enabled]

    def stages(self, context: PlantContext) -> list[PlantStage]:
        """Return the simulator's stage of every effect that is on, in model order."""
        return [
            effect.plant_stage(dict(getattr(self, effect.name).values), context)
            for effect in in_model_order(self.enabled_names())
        ]

    def with_switches(self, switches: dict[str, bool]) -> Effects:
        """Return a copy with ``enabled`` of the named effects replaced.

        Raises:
            EffectError: an unknown effect name.

        """
        _check_names(switches)
        return replace(
            self,
            settings=tuple(
                replace(s, enabled=bool(switches[s.name])) if s.name in switches else s
                for s in self.settings
            ),
        )

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> Effects:
        """Build from a scenario's ``effects`` mapping (``{name: {enabled: .., param: ..}}``).

        Raises:
            EffectError: unknown effect or parameter names, non-numeric or out-of-range values.

        """
        data = data or {}
        if not isinstance(data, dict):
            raise EffectError("effects must be a mapping of effect name -> settings")
        _check_names(data)
        built = []
        for default in _all_defaults():
            raw = data.get(default.name, {})
            settings = {"enabled": raw} if isinstance(raw, bool) else (raw or {})
            if not isinstance(settings, dict):
                raise EffectError(f"effects.{default.name} must be a mapping or a boolean")
            known = {"enabled", *(k for k, _ in default.values)}
            bad = set(settings) - known
            if bad:
                raise EffectError(
                    f"effects.{default.name}: unknown key(s) {sorted(bad)}; known {sorted(known)}"
                )
            values: dict[str, float] = {}
            for key, value in settings.items():
                if key == "enabled":
                    continue
                try:
                    values[key] = float(value)
                except (TypeError, ValueError):
                    raise EffectError(f"effects.{default.name}.{key} must be a number") from None
            built.append(
                replace(
                    default.with_values(**values),
                    enabled=bool(settings.get("enabled", default.enabled)),
                )
            )
        effects = cls(tuple(built))
        effects.validate()
        return effects

    def validate(self) -> None:
        """Raise :class:`EffectError` when a parameter is out of its declared range."""
        for s in self.settings:
            for p in registry()[s.name].plant:
                p.check(getattr(s, p.name), f"effects.{s.name}")

    def time_scaled(self, time_scale: float) -> Effects:
        """Return a copy whose slow (thermal, aging) times are multiplied by ``time_scale``."""
        scaled = []
        for s in self.settings:
            slow = {p.name: getattr(s, p.name) * time_scale for p in registry()[s.name].plant}
            keep = {p.name for p in registry()[s.name].plant if p.time_scaled}
            scaled.append(s.with_values(**{k: v for k, v in slow.items() if k in keep}))
        return replace(self, settings=tuple(scaled))


def _check_names(names: dict[str, Any]) -> None:
    unknown = set(names) - set(EFFECT_NAMES)
    if unknown:
        raise EffectError(f"unknown effect(s) {sorted(unknown)}; known: {list(EFFECT_NAMES)}")
