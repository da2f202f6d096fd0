"""ROS 2 node: temperature-compensated feedforward (``ros2 run es_feedforward feedforward_node``).

Subscribes ``/dm/setpoint`` (m) and ``/dm/temperature`` (degC), publishes one ``/dm/command``
(V) per set point received, computed for the whole grid with the newest temperature
(:mod:`es_feedforward.feedforward`). When no new command can be computed (missing, stale or
invalid temperature; malformed set point) it re-publishes the last good one (0 V before the
first), so a lockstep plant never waits; every such held command is counted, raises the
``feedforward: actuators`` status to WARN and is logged (at most once a second). Until its
inputs are connected (/dm/setpoint and, except ``uncompensated``, /dm/temperature matched to
a publisher) ``feedforward: ready`` on /diagnostics says "not ready" (a lockstep plant waits
for it). With ``sync_temperature`` (lockstep) it also counts /dm/temperature/raw samples and
holds a set point while the estimate of a sample received before it is owed
(:mod:`es_feedforward.estimate_sync`). Parameters: :mod:`es_feedforward.param_file` names,
declared with ranges; a run-time change is validated as a whole set and swapped in between
two set points. Environment: ``ES_DM_FEEDFORWARD_KERNELS=numpy`` runs the modes' inner
loops in plain numpy instead of the fused (numba) ones, same numbers
(:mod:`es_feedforward.kernels`).
"""

from __future__ import annotations

import time
from collections import deque
from typing import Final

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType, ROSClock
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.timer import Timer
from std_msgs.msg import Float64MultiArray

from es_feedforward.errors import ParameterError
from es_feedforward.estimate_sync import EstimateSync
from es_feedforward.feedforward import (
    CommandResult,
    Feedforward,
    FeedforwardConfig,
)
from es_feedforward.node_params import parameter_specs
from es_feedforward.param_file import (
    CALIBRATION_REASONS,
    CALIBRATION_VERDICT,
    config_from_parameters,
)
from es_msgs_py.arrays import LayoutError, msg_to_grid
from es_msgs_py.diagnostics import (
    Level,
    make_array,
    make_status,
    readiness_status,
    unmatched,
    unreached,
)
from es_msgs_py.grid_wire import GridWire
from es_msgs_py.topics import (
    COMMAND,
    DIAGNOSTICS,
    DM_QOS,
    SETPOINT,
    TEMPERATURE,
    TEMPERATURE_RAW,
    qos_for,
)
from es_node_runtime.node_main import run_node, summary_line, usage_text
from es_node_runtime.params import ParameterValues, declare_parameters
from es_node_runtime.readiness import Readiness
from es_physics.laws import Status

NODE_NAME: Final = "feedforward"
#: How many of the worst actuators the diagnostics name.
WORST_COUNT: Final = 5
_LEVEL_OF_STATUS: Final = {
    Status.OK: Level.OK,
    Status.OUT_OF_VALIDITY: Level.WARN,
    Status.CLIPPED_LOW: Level.WARN,
    Status.CLIPPED_HIGH: Level.WARN,
    Status.INVALID: Level.ERROR,
}
_OK: Final = int(Level.OK)
_WARN: Final = int(Level.WARN)
_ERROR: Final = int(Level.ERROR)
#: the diagnostic level (plain int) of each status code
_STATUS_LEVELS: Final = tuple(int(_LEVEL_OF_STATUS[s]) for s in Status)
#: Period [s, wall] of the readiness check until the node is ready.
READY_CHECK_PERIOD: Final = 0.05


def calibration_status(
    verdict: str, reasons: list[str]
) -> tuple[Level, DiagnosticStatus] | None:
    """Return the level and status ``feedforward: calibration`` for a verdict, None if trusted.

    A file without a verdict ("") says nothing either: no calibration judged it.
    """
    if verdict in ("", "trusted"):
        return None
    level = Level.ERROR if verdict == "unusable" else Level.WARN
    because = "; ".join(reasons) or "no reason given"
    message = f"calibration verdict {verdict}: {because}"
    values = {"verdict": verdict, **{f"reason_{i}": r for i, r in enumerate(reasons, 1)}}
    return level, make_status(f"{NODE_NAME}: calibration", level, message, values)


class FeedforwardNode(Node):
    """The feedforward node; all computation lives in :class:`Feedforward`."""

    def __init__(self) -> None:
        """Declare the parameters, build the core and the endpoints.

        Raises:
            ParameterError: a value rclpy refuses (e.g. integers for a double array).

        """
        super().__init__(NODE_NAME)
        clock = self.get_clock()
        assert isinstance(clock, ROSClock)  # a node's own clock is
        self._ros_clock: ROSClock = clock
        #: whether /clock drives the ROS time (use_sim_time), kept at each parameter change
        self._ros_time_active = clock.ros_time_is_active
        specs = parameter_specs()
        self._names = [spec.name for spec in specs]
        try:
            self._values = declare_parameters(self, specs)
        except ParameterException as err:  # e.g. an integer array given for a double array
            raise ParameterError(f"invalid parameter: {err}") from None
        config = config_from_parameters(self._values)
        self._core = Feedforward(config)
        self._pending: Feedforward | None = None
        self._reloads = 0
        self._rejected_reload: str | None = None
        self.add_on_set_parameters_callback(self._check_parameter_set)
        self.add_post_set_parameters_callback(self._swap_configuration)

        # deep publisher history: a recorder that lags for a moment still gets every command
        self._command_pub = self.create_publisher(Float64MultiArray, COMMAND, DM_QOS)
        # set points in and commands out as CDR bytes: no rclpy message objects per set point
        self._wire = GridWire(config.shape)
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, qos_for(DIAGNOSTICS))
        # In lockstep a step's estimate is sent before its set point, which must use it: the
        # events executor serves messages in arrival order, the single-threaded one serves
        # ready subscriptions in creation order, hence temperature first.
        self._temperature_sub = self.create_subscription(
            Float64MultiArray, TEMPERATURE, self._on_temperature, qos_for(TEMPERATURE)
        )
        # Lockstep: the raw samples come from the set points' publisher, before them, so
        # they say which estimates a set point must wait for (only their arrival matters).
        self._sync: EstimateSync | None = None
        self._raw_sub = None
        if self._values.get_bool("sync_temperature"):
            self._sync = EstimateSync(self._values.get_float("sync_timeout"))
            self._raw_sub = self.create_subscription(
                Float64MultiArray,
                TEMPERATURE_RAW,
                self._on_raw_sample,
                qos_for(TEMPERATURE_RAW),
                raw=True,
            )
        self._deferred: deque[bytes] = deque()  # serialised set points waiting for estimates
        self._sync_timer: Timer | None = None
        self._reported_sync_timeouts = 0
        self._setpoint_sub = self.create_subscription(
            Float64MultiArray, SETPOINT, self._on_setpoint, qos_for(SETPOINT), raw=True
        )
        self._counts = {
            "setpoints": 0, "commands": 0, "held": 0, "temperatures": 0, "waited": 0
        }
        self._hold_reason: str | None = None  # why the last command was held, None: it was not
        self._readiness = Readiness(
            self, self._unconnected_inputs, self._publish_diagnostics, READY_CHECK_PERIOD,
            on_ready=lambda: self.get_logger().info("ready: every input matched a publisher"),
        )
        self._rejected = {SETPOINT: 0, TEMPERATURE: 0}
        self._last_rejection: dict[str, str | None] = {SETPOINT: None, TEMPERATURE: None}
        self._last_result: CommandResult | None = None
        self._published_levels: tuple[int, ...] = ()
        self.create_timer(
            self._values.get_float("diagnostics_period"),
            self._publish_diagnostics,
            clock=Clock(clock_type=ClockType.STEADY_TIME),
        )
        rows, cols = config.shape
        self.get_logger().info(f"feedforward {rows} x {cols}, mode {config.mode.value}")
        self._calibration = calibration_status(
            self._values.get_str(CALIBRATION_VERDICT),
            [r for r in self._values.get_strs(CALIBRATION_REASONS) if r],
        )
        if self._calibration is not None:
            level, status = self._calibration
            log = self.get_logger().error if level is Level.ERROR else self.get_logger().warning
            log(f"parameters file: {status.message}")

    # --- data path -------------------------------------------------------------------------

    def _now(self) -> float:
        """Return the node's (ROS) time [s]."""
        if self._ros_time_active:
            return float(self._ros_clock.now().nanoseconds) * 1e-9
        # else the ROS clock reads the system clock: read it without an rclpy Time, which
        # costs 5 us on a warm core and about 20 us between set points (measured at 2 kHz)
        return time.time_ns() * 1e-9

    def _on_setpoint(self, msg: bytes) -> None:
        self._counts["setpoints"] += 1
        sync = self._sync
        if sync is not None and (self._deferred or sync.owed(time.monotonic())):
            self._deferred.append(msg)  # after any earlier one: commands keep their order
            self._counts["waited"] += 1
            self._arm_sync_timer()
            return
        self._command_for(msg)

    def _command_for(self, msg: bytes) -> None:
        """Compute and publish the command of one serialised set point (or hold the last one)."""
        try:
            setpoint = self._wire.decode(msg)
        except LayoutError as err:
            self._hold(f"set point rejected: {err}")
            self._reject(SETPOINT, str(err))  # its diagnostics count the held command
            return
        self._last_rejection[SETPOINT] = None
        now = self._now()
        result = self._core.command(setpoint, now)
        self._last_result = result
        if result.held:
            self._hold(result.problem or "no new command")
        else:
            self._hold_reason = None
            self._publish_command(result.voltage)
        self._publish_diagnostics_on_change(now)

    def _hold(self, reason: str) -> None:
        """Re-publish the last good command (0 V before the first); count and log it."""
        held = self._core.last_voltage
        self._publish_command(held)
        self._counts["held"] += 1
        self._hold_reason = reason
        zero = " (0 V: no good command yet)" if not np.any(held) else ""
        self.get_logger().warning(
            f"holding the last good command{zero}: {reason} "
            f"({self._counts['held']} held so far)",
            throttle_duration_sec=1.0,
        )

    def _on_temperature(self, msg: Float64MultiArray) -> None:
        self._counts["temperatures"] += 1
        self._take_temperature(msg)
        if self._sync is not None:
            self._sync.estimate()  # a rejected estimate answers its sample too
            self._release_deferred()

    def _take_temperature(self, msg: Float64MultiArray) -> None:
        try:
            temperature = msg_to_grid(msg, self._core.config.shape, copy=False)
        except LayoutError as err:
            self._reject(TEMPERATURE, str(err))
            return
        self._last_rejection[TEMPERATURE] = None
        now = self._now()
        problem = self._core.update_temperature(temperature, now)
        if problem is not None:
            self.get_logger().error(problem, throttle_duration_sec=1.0)
        self._publish_diagnostics_on_change(now)

    # --- lockstep: set points wait for their step's estimate --------------------------------

    def _on_raw_sample(self, _msg: bytes) -> None:
        assert self._sync is not None  # subscribed only with it
        self._sync.sample(time.monotonic())

    def _release_deferred(self) -> None:
        """Compute the waiting set points, oldest first, once no estimate is owed."""
        sync = self._sync
        assert sync is not None
        timed_out = sync.timed_out
        while self._deferred and not sync.owed(time.monotonic()):
            self._command_for(self._deferred.popleft())
        if sync.timed_out > timed_out:
            self.get_logger().warning(
                f"no /dm/temperature within sync_timeout of a /dm/temperature/raw sample: "
                f"used the newest estimate ({sync.timed_out} timed out so far)",
                throttle_duration_sec=1.0,
            )
        if sync.timed_out > self._reported_sync_timeouts:
            self._publish_diagnostics()  # WARN once per new timeout, then OK again
        if self._deferred:
            self._arm_sync_timer()

    def _arm_sync_timer(self) -> None:
        """Make sure a one-shot wall timer ends the wait at the oldest owed estimate's deadline."""
        if self._sync_timer is not None:
            return
        deadline = self._sync.deadline if self._sync is not None else None
        delay = 0.0 if deadline is None else max(deadline - time.monotonic(), 0.0)
        self._sync_timer = self.create_timer(
            delay, self._on_sync_timer, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )

    def _on_sync_timer(self) -> None:
        timer, self._sync_timer = self._sync_timer, None
        if timer is not None:
            self.destroy_timer(timer)
        self._release_deferred()

    def _publish_command(self, voltage: np.ndarray) -> None:
        self._command_pub.publish(self._wire.encode(voltage))
        self._counts["commands"] += 1

    def _unconnected_inputs(self) -> list[str]:
        """Return what readiness waits for: unmatched inputs, the command's subscribers."""
        needed = [self._setpoint_sub]
        if self._core.needs_temperature:
            needed.insert(0, self._temperature_sub)
        if self._raw_sub is not None:
            needed.insert(0, self._raw_sub)
        wanted = int(self._values["ready_subscribers"])  # type: ignore[call-overload]
        return [*unmatched(needed), *unreached(self._command_pub, wanted)]

    def _reject(self, topic: str, reason: str) -> None:
        self._rejected[topic] += 1
        self._last_rejection[topic] = reason
        self.get_logger().error(f"rejected {topic}: {reason}", throttle_duration_sec=1.0)
        self._publish_diagnostics_on_change()

    # --- parameters ------------------------------------------------------------------------

    def _check_parameter_set(self, params: list[Parameter]) -> SetParametersResult:
        """Validate the whole resulting parameter set and build the new core (not yet used)."""
        changes = {p.name: p.value for p in params if p.name in self._names}
        if not changes:  # e.g. use_sim_time: nothing of the feedforward changes
            self._pending = None
            return SetParametersResult(successful=True)
        candidate = {**self._values, **changes}
        try:
            config = config_from_parameters(candidate)
            self._pending = Feedforward(config, previous=self._core)
        except ValueError as err:
            self._rejected_reload = str(err)
            self._pending = None
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def _swap_configuration(self, params: list[Parameter]) -> None:
        """Swap the validated core in (same executor thread: never inside a set point)."""
        # rclpy's time source has applied any use_sim_time of this set to the clock
        self._ros_time_active = self._ros_clock.ros_time_is_active
        changed = {p.name: p.value for p in params if p.name in self._names}
        self._values = ParameterValues({**self._values, **changed})
        if self._pending is not None:
            self._core = self._pending
            self._pending = None
            self._reloads += 1
            self._rejected_reload = None
            self.get_logger().info(f"configuration reloaded (mode {self._core.config.mode.value})")
        self._publish_diagnostics_on_change()

    # --- diagnostics -----------------------------------------------------------------------

    def _statuses(self) -> list[DiagnosticStatus]:
        core = self._core
        config: FeedforwardConfig = core.config
        now = self._now()
        out = [readiness_status(NODE_NAME, self._readiness.waiting)]
        problem = core.temperature_problem(now)
        level = self._temperature_level(problem)
        if not core.needs_temperature:
            out.append(make_status(f"{NODE_NAME}: temperature", level, "not used (uncompensated)"))
        else:
            last_bad = self._last_rejection[TEMPERATURE]
            message = problem or (f"last message rejected: {last_bad}" if last_bad else "fresh")
            out.append(
                make_status(
                    f"{NODE_NAME}: temperature",
                    level,
                    message + (" (holding the last good command)" if problem else ""),
                    {
                        "received": self._counts["temperatures"],
                        "rejected": self._rejected[TEMPERATURE],
                        "timeout_s": config.temperature_timeout,
                        **self._sync_values(),
                    },
                )
            )
        out.append(self._actuator_status())
        last_bad = self._last_rejection[SETPOINT]
        out.append(
            make_status(
                f"{NODE_NAME}: setpoint",
                Level.ERROR if last_bad else Level.OK,
                f"last message rejected: {last_bad}" if last_bad else "ok",
                {
                    "received": self._counts["setpoints"],
                    "rejected": self._rejected[SETPOINT],
                    "commands": self._counts["commands"],
                    "held": self._counts["held"],
                },
            )
        )
        out.append(
            make_status(
                f"{NODE_NAME}: configuration",
                Level.OK,
                f"mode {config.mode.value}, {config.shape[0]} x {config.shape[1]}",
                {
                    "mode": config.mode.value,
                    "v_limit": config.v_limit,
                    "reloads": self._reloads,
                    "last_rejected_change": self._rejected_reload or "-",
                },
            )
        )
        counters = core.compensation_counters()
        if counters:
            missed = sum(counters.values())
            out.append(make_status(
                f"{NODE_NAME}: compensation",
                Level.WARN if missed else Level.OK,
                f"{missed} actuator command(s) beyond the compensation's reach (the closest "
                "sent)" if missed else "every command compensated",
                counters,
            ))
        if self._calibration is not None:
            out.append(self._calibration[1])
        return out

    def _sync_values(self) -> dict[str, object]:
        """Return the lockstep wait's counts (empty without ``sync_temperature``)."""
        if self._sync is None:
            return {}
        return {
            "setpoints_waited_for_estimate": self._counts["waited"],
            "estimates_timed_out": self._sync.timed_out,
        }

    def _actuator_status(self) -> DiagnosticStatus:
        name = f"{NODE_NAME}: actuators"
        result = self._last_result
        held = self._counts["held"]
        if result is None:
            if self._hold_reason is None:
                return make_status(name, Level.OK, "no set point yet")
            return make_status(
                name, Level.WARN, f"holding the last good command: {self._hold_reason}",
                {"held": held},
            )  # fmt: skip
        status = result.status.ravel()
        counts = np.bincount(status, minlength=len(Status))
        values: dict[str, object] = {s.name.lower(): int(counts[s]) for s in Status}
        values["held"] = held
        level = Level(_STATUS_LEVELS[result.worst])
        if level is not Level.OK:
            worst = np.argsort(-status, kind="stable")[:WORST_COUNT]
            cols = self._core.config.shape[1]
            for rank, index in enumerate(worst[status[worst] > 0], 1):
                values[f"worst_{rank}"] = (
                    f"{int(index)} (row {int(index) // cols}, col {int(index) % cols}): "
                    f"{Status(int(status[index])).name}"
                )
        if result.model_error is not None:
            values["max_model_error_m"] = float(np.max(np.abs(result.model_error)))
        bad = int(np.count_nonzero(status))
        message = "all ok" if not bad else f"{bad} actuator(s) not ok"
        if self._hold_reason is not None:
            message = f"holding the last good command: {self._hold_reason}"
            level = max(level, Level.WARN)
        return make_status(name, level, message, values)

    def _publish_diagnostics(self) -> None:
        statuses = self._statuses()
        if self._sync is not None:
            self._reported_sync_timeouts = self._sync.timed_out
        self._published_levels = tuple(s.level[0] for s in statuses)
        self._diag_pub.publish(make_array(self.get_clock().now().to_msg(), statuses))

    def _temperature_level(self, problem: str | None) -> Level:
        if not self._core.needs_temperature:
            return Level.OK
        if problem:
            return Level.ERROR
        late = self._sync is not None and self._sync.timed_out > self._reported_sync_timeouts
        return Level.WARN if self._last_rejection[TEMPERATURE] or late else Level.OK

    def _current_levels(self, now: float) -> tuple[int, ...]:
        """Cheap level summary to detect changes (same order as :meth:`_statuses`).

        Plain ints: this runs on every set point, and enum arithmetic costs microseconds.
        """
        temperature = int(self._temperature_level(self._core.temperature_problem(now)))
        result = self._last_result
        actuators = _OK if result is None else _STATUS_LEVELS[result.worst]
        if self._hold_reason is not None:
            actuators = max(actuators, _WARN)
        setpoint = _ERROR if self._last_rejection[SETPOINT] else _OK
        ready = _WARN if self._readiness.waiting else _OK
        calibration = () if self._calibration is None else (int(self._calibration[0]),)
        return (ready, temperature, actuators, setpoint, _OK, *calibration)

    def _publish_diagnostics_on_change(self, now: float | None = None) -> None:
        levels = self._current_levels(self._now() if now is None else now)
        if levels != self._published_levels:
            self._publish_diagnostics()

    def close(self) -> None:
        """Print the run's counts at exit, the lockstep waits included (nothing goes unsaid)."""
        c = self._counts
        text = (f"set points {c['setpoints']}, commands {c['commands']} (held {c['held']}), "
                f"temperatures {c['temperatures']}")
        if self._sync is not None:
            text += (f"; set points that waited for their estimate {c['waited']}, estimates "
                     f"timed out {self._sync.timed_out}, set points still waiting at the stop "
                     f"(no command) {len(self._deferred)}")
        summary_line(self.get_name(), text)


def main() -> int:
    """Run the node until SIGINT/SIGTERM."""
    return run_node(
        FeedforwardNode,
        help_text=usage_text("es_feedforward feedforward_node", __doc__ or "", parameter_specs()),
    )


if __name__ == "__main__":
    raise SystemExit(main())
