"""The plant node's parameters and what they make: the scenario and the lockstep settings.

Pure (no rclpy): :data:`SPECS` are the node's declared parameters (``plant_node --help``),
:func:`effect_specs` and :func:`resonance_spec` the ones whose defaults come from the chosen
scenario, :func:`configured_scenario` applies every override to the scenario, and
:func:`settings_from_parameters` gives the lockstep protocol's settings. A value of zero (or
-1 where zero is meaningful) keeps the scenario's own.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from es_msgs_py.topic_names import DM_DEPTH
from es_node_runtime.param_spec import ParameterSpec, ParameterValues
from es_sim_plant.effects import EFFECT_NAMES
from es_sim_plant.scenario import Scenario, load_scenario, resolve_scenario

__all__ = [
    "DELIVERY_WINDOW",
    "SPECS",
    "LockstepSettings",
    "base_scenario",
    "configured_scenario",
    "effect_specs",
    "resonance_spec",
    "settings_from_parameters",
]

#: Name of the parameter switching the self-sensing resonance sweeps on or off.
RESONANCE_PARAMETER = "resonance"
#: Prefix of the per-effect switches ``effects.<name>``.
EFFECT_PREFIX = "effects."
#: Lockstep steps between two waits for the readers' acknowledgements: a quarter of a
#: writer's history, so a reader that acknowledges within the wait has lost nothing.
DELIVERY_WINDOW = DM_DEPTH // 4


def _check_scenario(value: object) -> str | None:
    try:
        resolve_scenario(str(value))
    except ValueError as err:
        return str(err)
    return None


def _check_names(value: object) -> str | None:
    if not isinstance(value, list | tuple) or not all(isinstance(v, str) and v for v in value):
        return "wait_ready must be a list of node names"
    return None


SPECS: tuple[ParameterSpec, ...] = (
    ParameterSpec(
        "scenario",
        "dm_exposure",
        "Scenario: shipped name (thesis_ac, thesis_dc_ac, dm_exposure, characterisation) "
        "or path to a scenario YAML.",
        check=_check_scenario,
        read_only=True,
    ),
    ParameterSpec(
        "time_scale",
        0.0,
        "Multiplier of every slow time of the scenario (1 = physical length); 0 keeps the "
        "scenario's own (the shipped ones are shortened).",
        low=0.0,
        high=1000.0,
        read_only=True,
    ),
    ParameterSpec(
        "lockstep",
        True,
        "true: step only when the command of the step arrived (sim time, repeatable); "
        "false: free-running in real time.",
        read_only=True,
    ),
    ParameterSpec(
        "control_rate",
        0.0,
        "Control (command) rate, Hz; 0 keeps the scenario's (100 Hz for the closed-loop ones).",
        low=0.0,
        high=20000.0,
        read_only=True,
    ),
    ParameterSpec(
        "sensor_rate",
        0.0,
        "Temperature sample and heat-load rate, Hz (<= control_rate); 0 keeps the scenario's.",
        low=0.0,
        high=20000.0,
        read_only=True,
    ),
    ParameterSpec("rows", 0, "Grid rows; 0 keeps the scenario's.", 0, 256, read_only=True),
    ParameterSpec("cols", 0, "Grid columns; 0 keeps the scenario's.", 0, 256, read_only=True),
    ParameterSpec(
        "seed", -1, "Random seed; -1 keeps the scenario's.", -1, 2**31 - 1, read_only=True
    ),
    ParameterSpec(
        "duration",
        0.0,
        "Run length in simulation seconds; 0 keeps the scenario's (after time_scale).",
        low=0.0,
        high=1.0e7,
        read_only=True,
    ),
    ParameterSpec(
        "displacement_noise",
        -1.0,
        "Interferometer noise on /dm/displacement, m rms; -1 keeps the scenario's.",
        low=-1.0,
        high=1.0e-6,
        read_only=True,
    ),
    ParameterSpec(
        "publish_setpoints",
        True,
        "Publish the scenario's set points on /dm/setpoint.",
        read_only=True,
    ),
    ParameterSpec(
        "sync_temperature",
        True,
        "Lockstep: after each sensor sample wait for one /dm/temperature (when published).",
        read_only=True,
    ),
    ParameterSpec(
        "command_timeout",
        1.0,
        "Lockstep: wall seconds to wait for /dm/command before holding the last valid one.",
        low=0.001,
        high=60.0,
        read_only=True,
    ),
    ParameterSpec(
        "sync_timeout",
        1.0,
        "Lockstep: wall seconds to wait for /dm/temperature before continuing.",
        low=0.001,
        high=60.0,
        read_only=True,
    ),
    ParameterSpec(
        "delivery_timeout",
        2.0,
        f"Lockstep: every {DELIVERY_WINDOW} steps wait up to this many wall seconds for every "
        "reader (a recorder) to acknowledge what the plant published, so that no writer's "
        "history drops a message a reader still lacks (0: never wait).",
        low=0.0,
        high=60.0,
        read_only=True,
    ),
    ParameterSpec(
        "start_timeout",
        10.0,
        "Wall seconds to wait at start for the command (and temperature) publishers "
        "and the set-point subscriber before stepping anyway.",
        low=0.0,
        high=600.0,
        read_only=True,
    ),
    ParameterSpec(
        "wait_ready",
        [],
        "Lockstep: node names (e.g. thermal, feedforward) whose '<node>: ready' status on "
        "/diagnostics must be OK before the first step (within start_timeout); empty: none.",
        check=_check_names,
        read_only=True,
        dynamic_typing=True,  # an empty default has no array type of its own
    ),
    ParameterSpec(
        "start_subscribers",
        0,
        "At start also wait until every /dm topic the plant publishes has this many "
        "matched subscriptions beyond the controllers' (1: a recorder misses nothing).",
        0,
        100,
        read_only=True,
    ),
    ParameterSpec(
        "raw_subscribers",
        1,
        "Lockstep with sync_temperature: controller subscriptions /dm/temperature/raw must "
        "have matched before the first step, besides start_subscribers (1: the thermal "
        "node; 2 when the feedforward also counts the samples, sync_temperature there).",
        1,
        100,
        read_only=True,
    ),
    ParameterSpec(
        "max_speed",
        0.0,
        "Lockstep: run at most this many times faster than real time (0: no limit). A test "
        "stand waits for no controller: a recorder needs this to keep up.",
        0.0,
        1.0e6,
        read_only=True,
    ),
    ParameterSpec(
        "exit_when_done",
        False,
        "When the scenario ends: log a summary and exit 0 (else stay idle).",
        read_only=True,
    ),
)


def effect_specs(scenario: Scenario) -> list[ParameterSpec]:
    """Return the switches ``effects.<name>`` of every effect, defaulting to ``scenario``'s."""
    return [
        ParameterSpec(
            f"{EFFECT_PREFIX}{name}",
            bool(getattr(scenario.effects, name).enabled),
            f"Switch the '{name}' effect on or off (default: the scenario's setting; "
            "parameters of the effect come from the scenario).",
            read_only=True,
        )
        for name in EFFECT_NAMES
    ]


def resonance_spec(scenario: Scenario) -> ParameterSpec:
    """Return the switch of the resonance sweeps (/dm/resonance), defaulting to ``scenario``'s."""
    return ParameterSpec(
        RESONANCE_PARAMETER,
        scenario.resonance.enabled,
        "Publish /dm/resonance, the self-sensing sweeps (default: the scenario's "
        "setting; the sweep model comes from the scenario).",
        read_only=True,
    )


def base_scenario(values: ParameterValues) -> Scenario:
    """Load the scenario that ``scenario`` and ``time_scale`` name, before any override.

    Raises:
        ValueError: the scenario file is missing or malformed (the message says which).
        KeyError: ``values`` lack ``scenario`` or ``time_scale``.

    """
    time_scale = values.get_float("time_scale")
    return load_scenario(values.get_str("scenario"), time_scale or None)


def configured_scenario(
    scenario: Scenario, values: ParameterValues, switches: ParameterValues
) -> Scenario:
    """Return ``scenario`` with the node's overrides (grid, rates, seed, noise, switches).

    Args:
        scenario: the scenario of :func:`base_scenario`.
        values: the values of :data:`SPECS`.
        switches: the values of :func:`effect_specs` and :func:`resonance_spec`.

    Raises:
        ValueError: an override gives an out-of-range scenario (the message says which).
        KeyError: a parameter of :data:`SPECS` or a switch is missing from the values.
        es_node_runtime.errors.ParameterTypeError: a value has the wrong type.

    """

    def positive_or_none(key: str) -> float | None:
        value = values.get_float(key)
        return value if value > 0 else None

    def int_or_none(key: str, unset: int) -> int | None:
        value = values.get_int(key)
        return None if value == unset else value

    noise = values.get_float("displacement_noise")
    scenario = scenario.with_overrides(
        rows=int_or_none("rows", 0),
        cols=int_or_none("cols", 0),
        control_rate=positive_or_none("control_rate"),
        sensor_rate=positive_or_none("sensor_rate"),
        duration=positive_or_none("duration"),
        seed=int_or_none("seed", -1),
        effects={name: switches.get_bool(f"{EFFECT_PREFIX}{name}") for name in EFFECT_NAMES},
        displacement_noise=noise if noise >= 0.0 else None,
    )
    resonance_on = switches.get_bool(RESONANCE_PARAMETER)
    if resonance_on != scenario.resonance.enabled:
        scenario = replace(scenario, resonance=replace(scenario.resonance, enabled=resonance_on))
    return scenario


@dataclass(frozen=True)
class LockstepSettings:
    """How the node runs the plant (see ``plant_node --help`` for each parameter).

    Timeouts are wall seconds; ``max_speed`` is a factor over real time (0: no limit).
    """

    lockstep: bool = True
    publish_setpoints: bool = True
    sync_temperature: bool = True
    command_timeout: float = 1.0
    sync_timeout: float = 1.0
    delivery_timeout: float = 2.0
    start_timeout: float = 10.0
    wait_ready: tuple[str, ...] = ()
    start_subscribers: int = 0
    raw_subscribers: int = 1
    max_speed: float = 0.0
    exit_when_done: bool = False


def settings_from_parameters(values: ParameterValues) -> LockstepSettings:
    """Return the lockstep settings the values of :data:`SPECS` give.

    Raises:
        KeyError: a parameter of :data:`SPECS` is missing from ``values``.
        es_node_runtime.errors.ParameterTypeError: a value has the wrong type.

    """
    return LockstepSettings(
        lockstep=values.get_bool("lockstep"),
        publish_setpoints=values.get_bool("publish_setpoints"),
        sync_temperature=values.get_bool("sync_temperature"),
        command_timeout=values.get_float("command_timeout"),
        sync_timeout=values.get_float("sync_timeout"),
        delivery_timeout=values.get_float("delivery_timeout"),
        start_timeout=values.get_float("start_timeout"),
        wait_ready=tuple(values.get_strs("wait_ready")),
        start_subscribers=values.get_int("start_subscribers"),
        raw_subscribers=values.get_int("raw_subscribers"),
        max_speed=values.get_float("max_speed"),
        exit_when_done=values.get_bool("exit_when_done"),
    )

