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
crashed controller costs no timeouts. Every 250 steps it waits (``delivery_timeout`` wall s)
for every reader to acknowledge what it published, so a lagging recorder is never outrun by
more than a writer's history. After the last step it publishes the final clock and
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

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import Float64MultiArray

from es_msgs_py import topics
from es_msgs_py.arrays import LayoutError, grid_to_msg, msg_to_grid, sensors_to_msg
from es_msgs_py.diagnostics import make_array, make_status, published_status, ready_nodes
from es_node_runtime.node_main import (
    PublishCounter,
    deliver_and_report,
    deliver_pending,
    executor_spec,
    run_node,
    usage_text,
)
from es_node_runtime.param_spec import ParameterValues
from es_node_runtime.params import declare_parameters
from es_sim_plant.lockstep import FloatArray, Lockstep
from es_sim_plant.node_config import (
    SPECS,
    base_scenario,
    configured_scenario,
    effect_specs,
    resonance_spec,
    settings_from_parameters,
)
from es_sim_plant.plant import Plant

NODE_NAME = "plant"
#: Period of the wall watchdog that enforces the timeouts [s].
_WATCHDOG_PERIOD = 0.05
#: The node's parameters: the executor's and the configuration's. events: about half the
#: plant's CPU per lockstep step, but at small grids such a plant outruns a recorder (which
#: then loses messages), so single-threaded by default; a graph without a recorder picks
#: events (es_bringup.graph).
NODE_SPECS = (executor_spec("single_threaded"), *SPECS)
#: Longest wait [s wall] at the end of the run for every reader to acknowledge everything:
#: three of Fast DDS's 3 s heartbeats, on which a reader's missing samples are sent again
#: (measured: 3.3 s with a recorder stalled over the last 3 s of sim time). The end of a
#: run has no deadline; a hole in its record is what must not happen.
_FINAL_DELIVERY_LIMIT = 10.0
#: A warning of one kind is logged at most this often [s wall].
_WARN_THROTTLE = 1.0


def _stamp(seconds: float, stamp: Time | None = None) -> Time:
    """Return ``stamp`` (a new one if None) set to ``seconds`` [s]."""
    ns = round(seconds * 1e9)
    stamp = stamp if stamp is not None else Time()
    stamp.sec, stamp.nanosec = divmod(ns, 1_000_000_000)
    return stamp


class PlantNode(Node):
    """The plant core behind the es_dm topics (see the module docstring).

    The stepping protocol is :class:`es_sim_plant.lockstep.Lockstep`; this class declares
    the parameters, owns the endpoints and does the I/O the protocol asks for.
    """

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        values = declare_parameters(self, NODE_SPECS)
        scenario = base_scenario(values)
        switches = ParameterValues(
            {
                **declare_parameters(self, effect_specs(scenario)),
                **declare_parameters(self, [resonance_spec(scenario)]),
            }
        )
        scenario = configured_scenario(scenario, values, switches)
        settings = settings_from_parameters(values)
        self.plant = Plant(scenario)
        self.scenario = scenario
        self.settings = settings
        self._warned: dict[str, float] = {}

        # Graph queries take the topic names as remapped (a namespaced graph, -r rules).
        self._command_topic = self.resolve_topic_name(topics.COMMAND)
        self._temperature_topic = self.resolve_topic_name(topics.TEMPERATURE)
        qos = topics.DM_QOS  # deep history: a lagging recorder loses nothing
        # publish() serialises synchronously: one message per grid topic, refilled in place
        # each step (no message, layout and buffer built per step)
        self._grid_out = {
            topic: grid_to_msg(np.zeros(scenario.shape))
            for topic in (topics.DISPLACEMENT, topics.HEAT_LOAD, topics.SETPOINT)
        }
        self._clock_out = ClockMsg()  # refilled each step like the grids
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
        self.core = Lockstep(self.plant, self, settings)
        test_stand = self.core.test_stand
        self._pub_command = (
            self.create_publisher(Float64MultiArray, topics.COMMAND, qos) if test_stand else None
        )
        self._command_sub = (
            None
            if test_stand
            else self.create_subscription(
                Float64MultiArray, topics.COMMAND, self._on_command, qos
            )
        )
        # only the arrival counts: raw (serialised bytes), no Python message built per step
        self._temperature_sub = (
            self.create_subscription(
                Float64MultiArray, topics.TEMPERATURE, self._on_temperature, qos, raw=True
            )
            if settings.lockstep and settings.sync_temperature
            else None
        )
        if settings.lockstep and settings.wait_ready:
            self.create_subscription(
                DiagnosticArray, topics.DIAGNOSTICS, self._on_readiness, topics.DIAGNOSTICS_QOS
            )

        wall = Clock(clock_type=ClockType.STEADY_TIME)
        # A cancelled zero-period timer, reset to resume stepping after the executor served
        # other callbacks (a guard condition would do, but not every executor supports one).
        self._kick = self.create_timer(0.0, self._on_kick, clock=wall, autostart=False)
        self.create_timer(1.0, self.publish_diagnostics, clock=wall)
        if settings.lockstep:
            self.create_timer(_WATCHDOG_PERIOD, self.core.watchdog, clock=wall)
        else:
            self.create_timer(self.plant.dt, self.core.realtime_tick, clock=wall)
        # what it published per /dm topic, on /diagnostics: a recorder tells from it what it
        # has not received, the end of the run included (its last report comes after it)
        self._published = PublishCounter(self)
        self._announced_topics = {
            self.resolve_topic_name(t): t for t in (*topics.DM_TOPICS, *topics.OPTIONAL_DM_TOPICS)
        }
        self.get_logger().info(
            f"scenario '{scenario.name}': {scenario.rows} x {scenario.cols}, "
            f"{self.plant.steps} steps at {scenario.control_rate:g} Hz "
            f"({scenario.duration:g} s sim, time_scale {scenario.time_scale:g}), "
            f"{'lockstep' if settings.lockstep else 'real time'}, "
            f"effects: {', '.join(scenario.effects.enabled_names()) or 'none'}"
            + (", test stand (excitation)" if test_stand else "")
        )

    # --- inputs ---------------------------------------------------------------------------
    def _on_command(self, msg: Float64MultiArray) -> None:
        try:
            command = msg_to_grid(msg, self.plant.shape)
        except LayoutError as err:
            self.core.reject(str(err))
        else:
            self.core.command(command)

    def _on_readiness(self, msg: DiagnosticArray) -> None:
        """Note what the awaited nodes say about their readiness (only before the start)."""
        self.core.readiness(ready_nodes(msg))

    def _on_temperature(self, _msg: bytes) -> None:
        self.core.temperature()

    def _on_kick(self) -> None:
        self._kick.cancel()
        self.core.resume()

    # --- what the protocol asks for (es_sim_plant.lockstep.LockstepIo) ---------------------
    def peers_ready(self) -> bool:
        """Return whether the controllers' (and ``start_subscribers`` more) endpoints matched."""
        settings = self.settings
        # Matched subscriptions each output needs: the controller's (when the plant waits for
        # one) plus ``start_subscribers`` more (e.g. a recorder's).
        extra = settings.start_subscribers
        controlled = not self.core.test_stand
        thermal = controlled and settings.sync_temperature
        needed = [
            (self._pub_displacement, extra),
            (self._pub_raw, extra + thermal * settings.raw_subscribers),
            (self._pub_heat, extra + thermal),
            # a test stand publishes no set points
            (self._pub_setpoint, extra + 1 if controlled and settings.publish_setpoints else 0),
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
            return not settings.sync_temperature or temperature > 0
        ready = self._command_sub.get_publisher_count() > 0
        if settings.sync_temperature:
            ready = ready and temperature > 0
        return ready

    def sources(self) -> tuple[bool, bool]:
        """Return whether anything publishes /dm/command and /dm/temperature (graph query)."""
        return (
            self.count_publishers(self._command_topic) > 0,
            self.count_publishers(self._temperature_topic) > 0,
        )

    def publish_state(self) -> bool:
        """Publish /clock, /dm/displacement and a due sensor sample; return if one was due."""
        plant = self.plant
        _stamp(plant.time, self._clock_out.clock)
        self._pub_clock.publish(self._clock_out)
        self._pub_displacement.publish(self._filled(topics.DISPLACEMENT,
                                                    plant.measured_displacement()))
        if plant.done or not plant.sensor_due():
            return False
        self._pub_heat.publish(self._filled(topics.HEAT_LOAD, plant.heat_load()))
        swept = plant.read_resonance()
        if self._pub_resonance is not None and swept is not None:
            self._pub_resonance.publish(grid_to_msg(swept))
        self._pub_raw.publish(sensors_to_msg(plant.read_sensors()))
        return True

    def publish_setpoint(self) -> None:
        """Publish the scenario's set point of the current step on /dm/setpoint."""
        self._pub_setpoint.publish(self._filled(topics.SETPOINT, self.plant.setpoint()))

    def _filled(self, topic: str, grid: FloatArray) -> Float64MultiArray:
        """Return the reused message of ``topic`` holding ``grid`` (the plant's shape)."""
        msg = self._grid_out[topic]
        np.frombuffer(msg.data, np.float64).reshape(self.plant.shape)[...] = grid
        return msg

    def publish_command(self, command: FloatArray) -> None:
        """Publish the test stand's own command on /dm/command."""
        if self._pub_command is not None:
            self._pub_command.publish(grid_to_msg(command))

    def warn(self, kind: str, text: str) -> None:
        """Log a warning, at most one of each ``kind`` per second."""
        now = time.monotonic()
        if now - self._warned.get(kind, -_WARN_THROTTLE) >= _WARN_THROTTLE:
            self._warned[kind] = now
            self.get_logger().warning(text)

    def resume_later(self) -> None:
        """Resume stepping after the executor served other callbacks."""
        self._kick.reset()

    def delivered(self, limit: float) -> bool:
        """Wait up to ``limit`` wall s until every reader acknowledged everything published."""
        return not deliver_pending(self, limit)

    def finished(self) -> None:
        """Log the summary, publish the final diagnostics and, if asked, exit."""
        self.get_logger().info(self.core.summary(self.scenario.name))
        self.publish_diagnostics()
        if self.settings.exit_when_done:
            # Every reliable reader (a recorder) must hold every message before the writers
            # go. What a busy reader's full shared-memory port dropped is sent again only on
            # the writer's next heartbeat (Fast DDS: 3 s), so a wait bounded by the
            # command_timeout (0.1 s in a fault test) lost the run's last stretch from the
            # bag (issue 35); run_node's wait is skipped once the context is shut down.
            deliver_and_report(self, _FINAL_DELIVERY_LIMIT)
            rclpy.try_shutdown(context=self.context)

    def publish_diagnostics(self) -> None:
        """Publish the protocol's diagnostic aspects on /diagnostics."""
        statuses = [
            make_status(f"{NODE_NAME}: {aspect}", level, message, kv)
            for aspect, level, message, kv in self.core.statuses()
        ]
        announced = {
            self._announced_topics[t]: n
            for t, n in self._published.counts.items()
            if t in self._announced_topics
        }
        statuses.append(published_status(NODE_NAME, announced))
        self._pub_diag.publish(make_array(_stamp(self.plant.time), statuses))

    def close(self) -> None:
        """Nothing to flush: the plant keeps no files."""


def main(args: Sequence[str] | None = None) -> int:
    """Run the plant node until shutdown or, with ``exit_when_done``, the scenario's end."""
    return run_node(
        PlantNode, args, help_text=usage_text("es_sim_plant plant_node", __doc__ or "", NODE_SPECS)
    )


if __name__ == "__main__":
    raise SystemExit(main())
