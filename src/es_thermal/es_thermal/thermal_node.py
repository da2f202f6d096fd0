"""``ros2 run es_thermal thermal_node``: per-actuator temperature estimate for the feedforward.

Subscribes /dm/temperature/raw (sensor vector, degC) and, when published, /dm/heat_load
(grid, W per cell); publishes /dm/temperature (grid, degC) and /diagnostics.

By default one estimate is published per accepted raw message (event driven: the plant's
lockstep protocol waits for it); ``publish_rate > 0`` publishes the newest estimate on a
timer instead. The estimate comes from :class:`es_thermal.estimator.TemperatureEstimator`
(``estimator``: ``model`` = Kalman filter on the thermal network driven by the heat load,
``lowpass`` = the thesis's 0.1 Hz low-pass plus spatial interpolation).

Bad input never reaches the feedforward: a raw or heat-load message of the wrong layout or
size is rejected (log line, WARN diagnostic), and so is a heat load with NaN/inf, a negative
cell (beyond ``fault.heat_load_tolerance``) or a cell above ``fault.max_heat_load``: the last
accepted heat load is held; NaN/inf, out-of-range and stuck sensors are
excluded and the estimate continues from the others (WARN); with no valid sensor, or no raw
message for ``fault.stale_timeout`` wall seconds, the node publishes no estimate (ERROR), so
the feedforward holds, and it resumes by itself when valid readings return. ``thermal: ready``
on /diagnostics says "not ready" until /dm/temperature/raw has matched a publisher and
/dm/temperature ``ready_subscribers`` subscriptions (the graph's peers). Should an update
fail all the same (a bug, not bad input), the callback logs it, reports ERROR, publishes
nothing for that message and restarts the estimate from the next readings: the node keeps
running.

Self-sensing (optional): with ``resonance.f0_hz`` set (the parameters file that
``calibrate_resonance`` writes, :mod:`es_thermal.resonance_params`) the node also subscribes
/dm/resonance and /dm/command and corrects every actuator's model estimate with its own
resonance reading (:mod:`es_thermal.selfsensing`); implausible, stuck or stale channels
are dropped and reported in the ``thermal: self-sensing`` diagnostic. The command a sweep
ran under is found by the messages' publication stamps (``source_timestamp``, the
publishing host's clock: plant and controller on one host, or hosts with synchronised
clocks). Without ``resonance.f0_hz`` nothing changes.

Sensor positions: ``sensor_positions`` = flat [r0, c0, r1, c1, ...] (fractional row/col
allowed); empty = ``sensor_pitch`` (1: one sensor on every actuator, sensor i on actuator i;
p: one per p x p block at its centre). The thermal network's parameters (``thermal.*``) are
the mirror's as far as known. Every time-like parameter is physical; ``time_scale`` shortens
them all as the simulator's scenarios do (pass the scenario's value, e.g. 0.05 for
``dm_exposure``): capacitances, ``sensor_lag_tau`` and ``model.adaptation_time`` are
multiplied by it, ``lowpass.cutoff_hz`` divided, the model's noise intensities multiplied by
1/sqrt(time_scale).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from es_msgs_py import topics
from es_msgs_py.arrays import LayoutError, grid_to_msg, msg_to_grid, msg_to_sensors
from es_msgs_py.diagnostics import (
    Level,
    make_array,
    make_status,
    readiness_status,
    unmatched,
    unreached,
)
from es_node_runtime.errors import ParameterValueError
from es_node_runtime.node_main import executor_spec, run_node, usage_text
from es_node_runtime.params import declare_parameters
from es_node_runtime.readiness import Readiness
from es_thermal.estimator import SampleClock, TemperatureEstimator
from es_thermal.node_health import NodeHealth
from es_thermal.node_params import SPECS, config_from_parameters
from es_thermal.resonance_params import SPECS as RESONANCE_SPECS
from es_thermal.resonance_params import fusion_from_parameters
from es_thermal.sweep_sync import SampleSync

NODE_NAME = "thermal"
#: The executor without self-sensing: events (cheap per message: in lockstep every /clock
#: wakes the node). With self-sensing single-threaded: the self-sensing callbacks take the
#: message info (publication stamps), which rclpy's EventsExecutor does not pass.
EXECUTOR_SPEC = replace(
    executor_spec("events"),
    description=executor_spec().description
    + " With self-sensing (resonance.f0_hz set) only single_threaded, its default then.",
)


def _stamp(seconds: float) -> Time:
    ns = round(seconds * 1e9)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class ThermalNode(Node):
    """Thin ROS wrapper around :class:`TemperatureEstimator` (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        values = declare_parameters(self, SPECS)
        self.config = config_from_parameters(values)
        self.fusion = fusion_from_parameters(
            declare_parameters(self, RESONANCE_SPECS),
            self.config.rows * self.config.cols,
            values.get_float("time_scale"),
        )
        self._sync = (
            None if self.fusion is None else SampleSync(self.fusion, self.config.sample_period)
        )
        self._declare_executor()
        self._fused: np.ndarray | None = None  # the newest fused estimate
        started = time.perf_counter()
        self.core = TemperatureEstimator(self.config)
        self.get_logger().info(
            f"{self.config.kind} estimator for {self.config.rows} x {self.config.cols} actuators "
            f"and {self.config.sensor_count} sensors ready in "
            f"{time.perf_counter() - started:.2f} s"
        )
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self.health = NodeHealth(self.config, selfsensing=self.fusion is not None)
        self._sample_clock = SampleClock(self.config.sample_period)
        self._levels: dict[str, Level] = {}
        # deep publisher history: a recorder that lags for a moment still gets every estimate
        self._pub = self.create_publisher(
            Float64MultiArray, topics.TEMPERATURE, topics.DM_QOS
        )
        self._pub_diag = self.create_publisher(
            DiagnosticArray, topics.DIAGNOSTICS, topics.qos_for(topics.DIAGNOSTICS)
        )
        # Heat load first: the plant publishes a sample's heat load just before its readings,
        # which must use it; the events executor serves messages in arrival order, the
        # single-threaded one ready subscriptions in creation order.
        self.create_subscription(
            Float64MultiArray, topics.HEAT_LOAD, self._on_heat_load,
            topics.qos_for(topics.HEAT_LOAD),
        )
        if self.fusion is not None:  # the plant publishes a sweep just before its readings
            # two-argument callbacks get the message info (publication stamps); rclpy's
            # annotation only knows the one-argument form
            self.create_subscription(
                Float64MultiArray, topics.RESONANCE, self._on_resonance,  # type: ignore[arg-type]
                topics.qos_for(topics.RESONANCE),
            )
            self.create_subscription(
                Float64MultiArray, topics.COMMAND, self._on_command,  # type: ignore[arg-type]
                topics.qos_for(topics.COMMAND),
            )
        self._raw_sub = self.create_subscription(
            Float64MultiArray, topics.TEMPERATURE_RAW, self._on_raw,
            topics.qos_for(topics.TEMPERATURE_RAW),
        )
        # Readiness: the estimator is built; ready once the raw readings' publisher matched
        # and the estimates' publisher has matched its ``ready_subscribers``.
        self._ready_subscribers = values.get_int("ready_subscribers")
        self._readiness = Readiness(self, self._unready, self._publish_diagnostics, 0.05)
        period = values.get_float("diagnostics_period")
        self.create_timer(period, self._publish_diagnostics, clock=self._wall)
        rate = values.get_float("publish_rate")
        self._timer_mode = rate > 0.0
        if self._timer_mode:
            self.create_timer(1.0 / rate, self._publish_latest)

    def _declare_executor(self) -> None:
        """Declare ``executor``: events by default, single-threaded with self-sensing.

        Raises:
            ParameterValueError: ``executor`` is events with self-sensing configured.

        """
        selfsensing = self.fusion is not None
        spec = replace(EXECUTOR_SPEC, default="single_threaded") if selfsensing else EXECUTOR_SPEC
        kind = declare_parameters(self, [spec]).get_str(spec.name)
        if selfsensing and kind == "events":
            raise ParameterValueError(
                f"{spec.name}=events cannot run self-sensing (resonance.f0_hz set): its "
                "callbacks need the message info, which the EventsExecutor does not pass"
            )

    # --- input ------------------------------------------------------------------------------

    def _now(self) -> float:
        return float(self.get_clock().now().nanoseconds) * 1e-9

    def _wall_now(self) -> float:
        return float(self._wall.now().nanoseconds) * 1e-9

    def _reject(self, what: str, reason: str) -> None:
        self.health.rejected(what, reason, self._wall_now())
        self.get_logger().warning(
            f"rejected /dm/{'temperature/raw' if what == 'raw' else what} message: "
            f"{reason}",
            throttle_duration_sec=5.0,
        )
        self._publish_if_level_changed()

    def _fail(self, what: str, err: Exception) -> None:
        """Count and report an exception from the core; the estimate restarts afresh."""
        self.health.failed(what, err, self._wall_now())
        self.get_logger().error(
            f"{what} failed, estimate restarts from the next readings: "
            f"{type(err).__name__}: {err}",
            throttle_duration_sec=5.0,
        )
        self.core.restart()
        if self._sync is not None:
            self._sync.restart()
        self._publish_diagnostics()  # rare: report the ERROR at once

    def _on_heat_load(self, msg: Float64MultiArray) -> None:
        try:
            self.core.set_heat_load(msg_to_grid(msg, self.core.shape))
        except (LayoutError, ValueError) as err:
            self._reject("heat_load", str(err))
            return
        except Exception as err:  # the node must outlive any failure of the core
            self._fail("heat load", err)
            return
        self.health.heat_watch.feed(self._wall_now())

    def _on_resonance(self, msg: Float64MultiArray, info: dict[str, int]) -> None:
        assert self._sync is not None
        try:
            grid = msg_to_grid(msg, self.core.shape)
            self._sync.on_resonance(self._now(), int(info["source_timestamp"]), grid)
        except (LayoutError, ValueError) as err:
            self._reject("resonance", str(err))
        except Exception as err:  # the node must outlive any failure of the core
            self._fail("self-sensing", err)

    def _on_command(self, msg: Float64MultiArray, info: dict[str, int]) -> None:
        assert self._sync is not None
        try:
            grid = msg_to_grid(msg, self.core.shape)
            self._sync.on_command(int(info["source_timestamp"]), grid, self._now())
        except (LayoutError, ValueError) as err:
            self._reject("command", str(err))
        except Exception as err:  # the node must outlive any failure of the core
            self._fail("self-sensing", err)

    def _on_raw(self, msg: Float64MultiArray) -> None:
        try:
            readings = msg_to_sensors(msg, self.config.sensor_count)
        except LayoutError as err:
            self._reject("raw", str(err))
            return
        self.health.raw_watch.feed(self._wall_now())
        now = self._now()
        self.health.arrived(now)
        started = time.perf_counter()
        try:
            stamp = self._sample_clock.stamp(now)
            estimate = self.core.update(stamp, readings)
            temperatures = estimate.temperatures
            if self._sync is not None and temperatures is not None:
                temperatures = self._sync.on_estimate(stamp, now, temperatures)
        except Exception as err:  # the node must outlive any failure of the core
            self._fail("update", err)
            return
        self._fused = temperatures
        self.health.updated(time.perf_counter() - started)
        if temperatures is not None and not self._timer_mode:
            self._publish(temperatures)
        self._publish_if_level_changed()

    # --- output -----------------------------------------------------------------------------

    def _publish(self, temperatures: np.ndarray) -> None:
        self._pub.publish(grid_to_msg(temperatures))
        self.health.published += 1

    def _publish_latest(self) -> None:
        if self._fused is None or self.health.raw_watch.is_stale(self._wall_now()):
            return
        self._publish(self._fused)

    # --- diagnostics ------------------------------------------------------------------------

    def _unready(self) -> list[str]:
        """Return what readiness still waits for: the raw input, the estimates' subscribers."""
        return [*unmatched([self._raw_sub]), *unreached(self._pub, self._ready_subscribers)]

    def _statuses(self) -> list[DiagnosticStatus]:
        health, wall = self.health, self._wall_now()
        rows = [
            ("sensors", health.sensor_status(self.core.latest, wall)),
            ("input", health.input_status(wall)),
            ("estimate", health.estimate_status(self.core.model, self._fused, wall)),
        ]
        if self._sync is not None:
            rows.append(("self-sensing", health.selfsensing_status(self._sync, self._now())))
        out = [readiness_status(self.get_name(), self._readiness.waiting)]
        for aspect, (level, message, kv) in rows:
            self._levels[aspect] = level
            out.append(make_status(f"{self.get_name()}: {aspect}", level, message, kv))
        return out

    def _publish_if_level_changed(self) -> None:
        wall = self._wall_now()
        current = {
            "sensors": self.health.sensor_status(self.core.latest, wall)[0],
            "input": self.health.input_status(wall)[0],
        }
        if any(self._levels.get(k) != v for k, v in current.items()):
            self._publish_diagnostics()

    def _publish_diagnostics(self) -> None:
        array = make_array(_stamp(self._now()), self._statuses())
        self._pub_diag.publish(array)

    def close(self) -> None:
        """Nothing to flush: the node keeps no files."""


def main(args: Sequence[str] | None = None) -> int:
    """Run the thermal node until shutdown."""
    return run_node(
        ThermalNode, args, help_text=usage_text(
            "es_thermal thermal_node", __doc__ or "", (EXECUTOR_SPEC, *SPECS)
        )
    )


if __name__ == "__main__":
    raise SystemExit(main())
