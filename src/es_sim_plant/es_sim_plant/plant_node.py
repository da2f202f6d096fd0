"""``ros2 run es_sim_plant plant_node``: the simulated mirror as a ROS 2 node that owns time.

Subscribes /dm/command (and /dm/temperature in lockstep with ``sync_temperature``);
publishes /clock, /dm/displacement (truth, or measured when the scenario adds
``displacement_noise``), /dm/temperature/raw and /dm/heat_load (at ``sensor_rate``),
/dm/setpoint (the scenario reference, ``publish_setpoints``) and /diagnostics; with the
scenario's resonance measurement on (or parameter ``resonance``) also /dm/resonance, the
self-sensing sweeps, at ``sensor_rate`` just before each /dm/temperature/raw.

Lockstep (default ``lockstep: true``), per control step k, exactly as docs/architecture.md
"Lockstep (sim time) protocol": /clock = t_k; /dm/displacement; when a sensor sample is due
/dm/heat_load and /dm/temperature/raw, then (``sync_temperature``) wait for one
/dm/temperature (``sync_timeout`` wall s -> continue, WARN); /dm/setpoint; wait for one
/dm/command (``command_timeout`` wall s -> hold the last valid command, WARN); step. The
first step waits (up to ``start_timeout``) for the peers' endpoints and for every node in
``wait_ready`` to report "<node>: ready" OK on /diagnostics. When
nothing publishes the awaited topic at all, the plant does not wait for it (WARN), so a
crashed controller costs no timeouts. After the last step it publishes the final clock and
displacement, logs a summary and, with ``exit_when_done``, exits 0.

Real time (``lockstep: false``): once the peers are present as in lockstep (or after
``start_timeout``), a wall timer at the control rate publishes the outputs of step k and
applies the newest valid command.

Scenarios with an ``excitation`` (test-stand runs such as ``characterisation``) need no
controller: the plant plays the voltage program itself and publishes it on /dm/command, as
a test stand's signal generator would be recorded.

Bad commands (wrong layout or size, non-finite values, beyond the amplifier limit) are
rejected with a log line and a WARN diagnostic; the last valid command stays applied.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace
from enum import Enum, auto

import numpy as np
import numpy.typing as npt
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import Float64MultiArray

from es_msgs_py import topics
from es_msgs_py.arrays import LayoutError, grid_to_msg, msg_to_grid, sensors_to_msg
from es_msgs_py.diagnostics import Level, make_array, make_status, ready_nodes
from es_msgs_py.node_main import executor_spec, run_node, usage_text
from es_msgs_py.params import ParameterSpec, declare_parameters
from es_sim_plant.effects import EFFECT_NAMES
from es_sim_plant.plant import Plant
from es_sim_plant.scenario import load_scenario, resolve_scenario

FloatArray = npt.NDArray[np.float64]

NODE_NAME = "plant"
#: Longest stretch [s wall] the plant steps without returning to the executor.
_BATCH_WALL = 0.02
#: Period of the wall watchdog that enforces the timeouts [s].
_WATCHDOG_PERIOD = 0.05
#: How often the watchdog refreshes who publishes commands and temperatures [s wall].
_GRAPH_PERIOD = 0.2


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
    # events: ~half the plant's CPU per lockstep step, but the recorder's late match of the
    # thermal node's estimates (a known race) then loses the first ones more often
    executor_spec("single_threaded"),
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


class Phase(Enum):
    """Where the lockstep protocol stands within the current step."""

    STARTING = auto()
    BEGIN = auto()
    WAIT_TEMPERATURE = auto()
    SETPOINT = auto()
    WAIT_COMMAND = auto()
    DONE = auto()


def _stamp(seconds: float) -> Time:
    ns = round(seconds * 1e9)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class PlantNode(Node):
    """The plant core behind the es_dm topics (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        values = declare_parameters(self, SPECS)
        time_scale = float(values["time_scale"])  # type: ignore[arg-type]
        scenario = load_scenario(str(values["scenario"]), time_scale or None)
        effect_specs = [
            ParameterSpec(
                f"effects.{name}",
                bool(getattr(scenario.effects, name).enabled),
                f"Switch the '{name}' effect on or off (default: the scenario's setting; "
                "parameters of the effect come from the scenario).",
                read_only=True,
            )
            for name in EFFECT_NAMES
        ]
        effect_values = declare_parameters(self, effect_specs)
        resonance_on = declare_parameters(
            self,
            [
                ParameterSpec(
                    "resonance",
                    scenario.resonance.enabled,
                    "Publish /dm/resonance, the self-sensing sweeps (default: the scenario's "
                    "setting; the sweep model comes from the scenario).",
                    read_only=True,
                )
            ],
        )["resonance"]

        def positive_or_none(key: str) -> float | None:
            value = float(values[key])  # type: ignore[arg-type]
            return value if value > 0 else None

        def int_or_none(key: str, unset: int) -> int | None:
            value = int(values[key])  # type: ignore[call-overload]
            return None if value == unset else value

        noise = float(values["displacement_noise"])  # type: ignore[arg-type]
        scenario = scenario.with_overrides(
            rows=int_or_none("rows", 0),
            cols=int_or_none("cols", 0),
            control_rate=positive_or_none("control_rate"),
            sensor_rate=positive_or_none("sensor_rate"),
            duration=positive_or_none("duration"),
            seed=int_or_none("seed", -1),
            effects={name: bool(effect_values[f"effects.{name}"]) for name in EFFECT_NAMES},
            displacement_noise=noise if noise >= 0.0 else None,
        )
        if bool(resonance_on) != scenario.resonance.enabled:
            scenario = replace(
                scenario, resonance=replace(scenario.resonance, enabled=bool(resonance_on))
            )
        self.plant = Plant(scenario)
        self.scenario = scenario
        self.lockstep = bool(values["lockstep"])
        self.publish_setpoints = bool(values["publish_setpoints"])
        self.sync_temperature = bool(values["sync_temperature"])
        self.command_timeout = float(values["command_timeout"])  # type: ignore[arg-type]
        self.sync_timeout = float(values["sync_timeout"])  # type: ignore[arg-type]
        self.start_timeout = float(values["start_timeout"])  # type: ignore[arg-type]
        self.start_subscribers = int(values["start_subscribers"])  # type: ignore[call-overload]
        self.exit_when_done = bool(values["exit_when_done"])
        self.max_speed = float(values["max_speed"])  # type: ignore[arg-type]
        # Nodes whose readiness the first step waits for, and what they said last.
        wait_ready = values["wait_ready"]
        assert isinstance(wait_ready, list | tuple)  # _check_names made sure
        self._wait_ready: dict[str, bool] = dict.fromkeys(map(str, wait_ready), False)
        self._paced = False

        # Graph queries take the topic names as remapped (a namespaced graph, -r rules).
        self._command_topic = self.resolve_topic_name(topics.COMMAND)
        self._temperature_topic = self.resolve_topic_name(topics.TEMPERATURE)
        qos = topics.DM_QOS  # deep history: a lagging recorder loses nothing
        self._pub_clock = self.create_publisher(ClockMsg, topics.CLOCK, topics.CLOCK_QOS)
        self._pub_displacement = self.create_publisher(Float64MultiArray, topics.DISPLACEMENT, qos)
        self._pub_raw = self.create_publisher(Float64MultiArray, topics.TEMPERATURE_RAW, qos)
        self._pub_heat = self.create_publisher(Float64MultiArray, topics.HEAT_LOAD, qos)
        self._pub_setpoint = self.create_publisher(Float64MultiArray, topics.SETPOINT, qos)
        self._pub_resonance = (
            None
            if self.plant.resonance is None
            else self.create_publisher(Float64MultiArray, topics.RESONANCE, qos)
        )
        self._pub_diag = self.create_publisher(
            DiagnosticArray, topics.DIAGNOSTICS, topics.DIAGNOSTICS_QOS
        )
        self._test_stand = self.plant.excitation is not None
        self._pub_command = (
            self.create_publisher(Float64MultiArray, topics.COMMAND, qos)
            if self._test_stand
            else None
        )
        self._command_sub = (
            None
            if self._test_stand
            else self.create_subscription(
                Float64MultiArray, topics.COMMAND, self._on_command, qos
            )
        )
        self._temperature_sub = (
            self.create_subscription(
                Float64MultiArray, topics.TEMPERATURE, self._on_temperature, qos
            )
            if self.lockstep and self.sync_temperature
            else None
        )
        if self.lockstep and self._wait_ready:
            self.create_subscription(
                DiagnosticArray, topics.DIAGNOSTICS, self._on_readiness, topics.DIAGNOSTICS_QOS
            )

        # Command state: the last valid command stays applied until a valid one replaces it.
        self._held = np.zeros(self.plant.shape)
        self._last_command_wall = time.monotonic()
        self.counts = {
            "commands": 0,
            "rejected": 0,
            "command_timeouts": 0,
            "no_command_source": 0,
            "sync_timeouts": 0,
        }
        self._last_reject = ""
        self._reported_counts = dict(self.counts)
        self._levels: dict[str, Level] = {}

        # Graph queries cost ~0.1 ms: the hot path reads these, the watchdog refreshes them.
        self._has_command_source = False
        self._has_temperature_source = False
        self._graph_checked = 0.0
        wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._phase = Phase.STARTING
        self._deadline = 0.0
        self._start_wall = time.monotonic()
        self._run_wall_start = 0.0
        self._run_cpu_start = 0.0
        # A cancelled zero-period timer, reset to resume stepping after the executor served
        # other callbacks (a guard condition would do, but not every executor supports one).
        self._kick = self.create_timer(0.0, self._on_kick, clock=wall, autostart=False)
        self.create_timer(1.0, self._publish_diagnostics, clock=wall)
        if self.lockstep:
            self.create_timer(_WATCHDOG_PERIOD, self._watchdog, clock=wall)
        else:
            self.create_timer(self.plant.dt, self._realtime_tick, clock=wall)
        self.get_logger().info(
            f"scenario '{scenario.name}': {scenario.rows} x {scenario.cols}, "
            f"{self.plant.steps} steps at {scenario.control_rate:g} Hz "
            f"({scenario.duration:g} s sim, time_scale {scenario.time_scale:g}), "
            f"{'lockstep' if self.lockstep else 'real time'}, "
            f"effects: {', '.join(scenario.effects.enabled_names()) or 'none'}"
            + (", test stand (excitation)" if self._test_stand else "")
        )

    # --- inputs ---------------------------------------------------------------------------
    def _on_command(self, msg: Float64MultiArray) -> None:
        try:
            command = msg_to_grid(msg, self.plant.shape)
        except LayoutError as err:
            self._reject(str(err))
        else:
            reason = self.plant.check_command(command)
            if reason is None:
                self._held = command
                self.counts["commands"] += 1
                self._last_command_wall = time.monotonic()
            else:
                self._reject(reason)
        if self._phase is Phase.WAIT_COMMAND:
            self._apply_and_continue()

    def _reject(self, reason: str) -> None:
        self.counts["rejected"] += 1
        self._report_problem("commands")
        self._last_reject = reason
        self.get_logger().warning(
            f"command rejected, holding the last valid one: {reason}", throttle_duration_sec=1.0
        )

    def _on_readiness(self, msg: DiagnosticArray) -> None:
        """Note what the awaited nodes say about their readiness (only before the start)."""
        for name, ready in ready_nodes(msg).items():
            if name in self._wait_ready:
                self._wait_ready[name] = ready

    def _not_ready(self) -> list[str]:
        """Return the awaited nodes that have not said they are ready."""
        return [name for name, ready in self._wait_ready.items() if not ready]

    def _on_temperature(self, _msg: Float64MultiArray) -> None:
        if self._phase is Phase.WAIT_TEMPERATURE:
            self._phase = Phase.SETPOINT
            self._advance()

    # --- lockstep -------------------------------------------------------------------------
    def _peers_ready(self) -> bool:
        # Matched subscriptions each output needs: the controller's (when the plant waits for
        # one) plus ``start_subscribers`` more (e.g. a recorder's).
        extra = self.start_subscribers
        controlled = not self._test_stand
        thermal = controlled and self.sync_temperature
        needed = [
            (self._pub_displacement, extra),
            (self._pub_raw, extra + thermal),
            (self._pub_heat, extra + thermal),
            # a test stand publishes no set points
            (self._pub_setpoint, extra + 1 if controlled and self.publish_setpoints else 0),
        ]
        if self._pub_command is not None:
            needed.append((self._pub_command, extra))
        if any(pub.get_subscription_count() < count for pub, count in needed):
            return False
        # Sources: publishers matched by the plant's own subscription (nothing sent before
        # the match is lost), the graph's count where the plant does not subscribe.
        temperature = (
            self._temperature_sub.get_publisher_count()
            if self._temperature_sub is not None
            else self.count_publishers(self._temperature_topic)
        )
        if self._command_sub is None:
            return not self.sync_temperature or temperature > 0
        ready = self._command_sub.get_publisher_count() > 0
        if self.sync_temperature:
            ready = ready and temperature > 0
        return ready

    def _started(self, now: float) -> bool:
        """Begin the run once the peers are present and ready, or ``start_timeout`` passed."""
        if not (self._peers_ready() and not self._not_ready()):
            if now - self._start_wall < self.start_timeout:
                return False
            not_ready = self._not_ready()
            self.get_logger().warning(
                f"start: peers not all present after {self.start_timeout:g} s"
                + (f" (not ready: {', '.join(not_ready)})" if not_ready else "")
                + "; stepping anyway"
            )
        self._phase = Phase.BEGIN
        self._run_wall_start = now
        self._run_cpu_start = time.process_time()
        return True

    def _refresh_graph(self, now: float) -> None:
        self._graph_checked = now
        self._has_command_source = self.count_publishers(self._command_topic) > 0
        self._has_temperature_source = self.count_publishers(self._temperature_topic) > 0

    def _watchdog(self) -> None:
        now = time.monotonic()
        if now - self._graph_checked >= _GRAPH_PERIOD:
            self._refresh_graph(now)
        if self._phase is Phase.STARTING:
            if self._started(now):
                self._refresh_graph(now)
                self._advance()
            return
        if self._paced:
            self._paced = False
            self._advance()
            return
        if self._phase is Phase.WAIT_TEMPERATURE and now > self._deadline:
            self.counts["sync_timeouts"] += 1
            self._report_problem("sync")
            self.get_logger().warning(
                f"no /dm/temperature within {self.sync_timeout:g} s: continuing",
                throttle_duration_sec=1.0,
            )
            self._phase = Phase.SETPOINT
            self._advance()
        elif self._phase is Phase.WAIT_COMMAND and now > self._deadline:
            self.counts["command_timeouts"] += 1
            self._report_problem("commands")
            self.get_logger().warning(
                f"no /dm/command within {self.command_timeout:g} s: holding the last valid one",
                throttle_duration_sec=1.0,
            )
            self._apply_and_continue()

    def _apply_and_continue(self) -> None:
        self.plant.step(self._held)
        self._phase = Phase.BEGIN
        self._advance()

    def _advance(self) -> None:
        """Run the protocol until it must wait for a message, or for a short wall budget."""
        budget_end = time.monotonic() + _BATCH_WALL
        while True:
            if self._phase is Phase.BEGIN:
                if self.plant.done:
                    self._publish_state()
                    self._finish()
                    return
                if self._ahead_of_max_speed():
                    self._paced = True  # the watchdog resumes
                    return
                due = self._publish_state()
                if due and self.sync_temperature:
                    if self._has_temperature_source:
                        self._phase = Phase.WAIT_TEMPERATURE
                        self._deadline = time.monotonic() + self.sync_timeout
                        return
                    self.counts["sync_timeouts"] += 1
                    self._report_problem("sync")
                self._phase = Phase.SETPOINT
            if self._phase is Phase.SETPOINT:
                if self._test_stand:
                    self._play_excitation()
                else:
                    if self.publish_setpoints:
                        self._pub_setpoint.publish(grid_to_msg(self.plant.setpoint()))
                    if self._has_command_source:
                        self._phase = Phase.WAIT_COMMAND
                        self._deadline = time.monotonic() + self.command_timeout
                        return
                    self.counts["no_command_source"] += 1
                    self._report_problem("commands")
                    self.plant.step(self._held)
                self._phase = Phase.BEGIN
            if self._phase is not Phase.BEGIN:
                return
            if time.monotonic() > budget_end:
                self._kick.reset()  # continue after the executor served other callbacks
                return

    def _on_kick(self) -> None:
        self._kick.cancel()
        self._advance()

    def _ahead_of_max_speed(self) -> bool:
        if self.max_speed <= 0.0:
            return False
        return self.plant.time > (time.monotonic() - self._run_wall_start) * self.max_speed

    def _play_excitation(self) -> None:
        command = self.plant.excitation_command()
        if command is None:
            return
        if self._pub_command is not None:
            self._pub_command.publish(grid_to_msg(command))
        self._held = command
        self.plant.step(command)

    def _publish_state(self) -> bool:
        """Publish /clock, /dm/displacement and a due sensor sample; return if one was due."""
        plant = self.plant
        self._pub_clock.publish(ClockMsg(clock=_stamp(plant.time)))
        self._pub_displacement.publish(grid_to_msg(plant.measured_displacement()))
        if plant.done or not plant.sensor_due():
            return False
        self._pub_heat.publish(grid_to_msg(plant.heat_load()))
        swept = plant.read_resonance()
        if self._pub_resonance is not None and swept is not None:
            self._pub_resonance.publish(grid_to_msg(swept))
        self._pub_raw.publish(sensors_to_msg(plant.read_sensors()))
        return True

    # --- real time ------------------------------------------------------------------------
    def _realtime_tick(self) -> None:
        if self._phase is Phase.STARTING and not self._started(time.monotonic()):
            return
        if self._phase is not Phase.BEGIN:
            return
        if self.plant.done:
            self._publish_state()
            self._finish()
            return
        self._publish_state()
        if self._test_stand:
            self._play_excitation()
            return
        if self.publish_setpoints:
            self._pub_setpoint.publish(grid_to_msg(self.plant.setpoint()))
        if time.monotonic() - self._last_command_wall > self.command_timeout:
            self.counts["command_timeouts"] += 1
            self._last_command_wall = time.monotonic()
        self.plant.step(self._held)

    # --- end and diagnostics ----------------------------------------------------------------
    def _finish(self) -> None:
        self._phase = Phase.DONE
        wall = max(time.monotonic() - self._run_wall_start, 1e-9)
        cpu_per_step = (time.process_time() - self._run_cpu_start) / max(self.plant.k, 1)
        sim = self.plant.time
        counts = ", ".join(f"{k} {v}" for k, v in self.counts.items())
        self.get_logger().info(
            f"scenario '{self.scenario.name}' finished: {self.plant.k} steps, {sim:g} s sim in "
            f"{wall:.2f} s wall ({sim / wall:.2f}x real time, {self.plant.k / wall:.0f} "
            f"steps/s, plant CPU {cpu_per_step * 1e3:.3f} ms/step); {counts}"
        )
        self._publish_diagnostics()
        if self.exit_when_done:
            # Reliable subscribers (a recorder) must get the final displacement before exit.
            timeout = rclpy.duration.Duration(seconds=self.command_timeout)
            for pub in (self._pub_displacement, self._pub_setpoint, self._pub_raw, self._pub_diag):
                pub.wait_for_all_acked(timeout)
            if self._pub_resonance is not None:
                self._pub_resonance.wait_for_all_acked(timeout)
            rclpy.try_shutdown(context=self.context)

    def _statuses(self) -> list[DiagnosticStatus]:
        c = self.counts
        new = {k: c[k] - self._reported_counts.get(k, 0) for k in c}
        self._reported_counts = dict(c)
        command_problems = new["rejected"] + new["command_timeouts"] + new["no_command_source"]
        statuses: list[tuple[str, Level, str, dict[str, object]]] = [
            (
                "commands",
                Level.WARN if command_problems else Level.OK,
                (
                    f"last: {self._last_reject}" if new["rejected"] else
                    "timeouts: holding the last valid command" if new["command_timeouts"] else
                    "no /dm/command publisher: holding the last valid command"
                    if new["no_command_source"] else "commands arriving"
                ),
                {k: c[k] for k in ("commands", "rejected", "command_timeouts",
                                   "no_command_source")},
            ),
            (
                "sync",
                Level.WARN if new["sync_timeouts"] else Level.OK,
                "/dm/temperature timed out or absent" if new["sync_timeouts"] else "in step",
                {"sync_timeouts": c["sync_timeouts"], "lockstep": self.lockstep},
            ),
            (
                "scenario",
                Level.OK,
                "finished" if self._phase is Phase.DONE else
                "waiting for peers" if self._phase is Phase.STARTING else "running",
                {
                    "scenario": self.scenario.name,
                    "step": self.plant.k,
                    "steps": self.plant.steps,
                    "sim_time_s": float(self.plant.time),
                    "effects": ",".join(self.scenario.effects.enabled_names()) or "none",
                },
            ),
        ]  # fmt: skip
        out: list[DiagnosticStatus] = []
        for aspect, level, message, kv in statuses:
            self._levels[aspect] = level
            out.append(make_status(f"{NODE_NAME}: {aspect}", level, message, kv))
        return out

    def _report_problem(self, aspect: str) -> None:
        """Publish diagnostics at once when ``aspect`` turns from OK to WARN."""
        if self._levels.get(aspect, Level.OK) is Level.OK:
            self._publish_diagnostics()

    def _publish_diagnostics(self) -> None:
        self._pub_diag.publish(make_array(_stamp(self.plant.time), self._statuses()))

    def close(self) -> None:
        """Nothing to flush: the plant keeps no files."""


def main(args: Sequence[str] | None = None) -> int:
    """Run the plant node until shutdown or, with ``exit_when_done``, the scenario's end."""
    return run_node(
        PlantNode, args, help_text=usage_text("es_sim_plant plant_node", __doc__ or "", SPECS)
    )


if __name__ == "__main__":
    raise SystemExit(main())
