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

import array
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import fields

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
from es_msgs_py.node_main import run_node, usage_text
from es_msgs_py.params import ParameterSpec, declare_parameters
from es_thermal.estimator import (
    ESTIMATORS,
    EstimatorConfig,
    SampleClock,
    TemperatureEstimator,
)
from es_thermal.faults import FaultConfig, StaleWatch
from es_thermal.interpolation import block_centre_positions, sensor_positions
from es_thermal.kalman import KalmanTuning
from es_thermal.lowpass import DEFAULT_CUTOFF_HZ, DEFAULT_ORDER
from es_thermal.network import NetworkParams
from es_thermal.resonance_params import SPECS as RESONANCE_SPECS
from es_thermal.resonance_params import fusion_from_parameters
from es_thermal.sweep_sync import SampleSync

NODE_NAME = "thermal"
#: Measured sample intervals this far off the configured ``sample_rate`` give a WARN.
_RATE_TOLERANCE = 0.25
#: A rejected message keeps the input diagnostic at WARN (a failed update the estimate
#: diagnostic at ERROR) this long [wall s].
_REJECTION_HOLD = 5.0
#: Updates the estimate diagnostic's timing and rate figures cover.
_WINDOW = 200


def _check_positions(value: object) -> str | None:
    if isinstance(value, bytes | bytearray) and not value:
        return None  # the untyped empty default
    ok = isinstance(value, list | tuple | array.array) and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value
    )
    if not ok:
        return "sensor_positions must be a list of numbers [r0, c0, r1, c1, ...]"
    if len(value) % 2:  # type: ignore[arg-type]
        return "sensor_positions needs an even count [r0, c0, r1, c1, ...]"
    return None


_NETWORK = NetworkParams()
_TUNING = KalmanTuning(sensor_noise=0.02)
_FAULTS = FaultConfig()

SPECS: tuple[ParameterSpec, ...] = (
    ParameterSpec(
        "estimator",
        "model",
        "Estimator: 'model' = Kalman filter on the thermal network driven by /dm/heat_load; "
        "'lowpass' = the thesis's low-pass filter (lowpass.cutoff_hz) plus spatial "
        "interpolation between sensors.",
        choices=ESTIMATORS,
        read_only=True,
    ),
    ParameterSpec("rows", 12, "Actuator grid rows.", 1, 256, read_only=True),
    ParameterSpec("cols", 12, "Actuator grid columns.", 1, 256, read_only=True),
    ParameterSpec(
        "sensor_positions",
        [],
        "Sensor (row, col) positions, flat [r0, c0, r1, c1, ...], fractional allowed; "
        "empty: see sensor_pitch.",
        check=_check_positions,
        read_only=True,
        dynamic_typing=True,  # an empty default has no array type of its own
    ),
    ParameterSpec(
        "sensor_pitch",
        1,
        "Without sensor_positions: one sensor per pitch x pitch actuators at the block "
        "centre (1: sensor i on actuator i).",
        1,
        64,
        read_only=True,
    ),
    ParameterSpec(
        "sample_rate", 10.0, "Sensor sample rate the filters are built for, Hz.", 0.01, 10000.0,
        read_only=True,
    ),
    ParameterSpec(
        "publish_rate",
        0.0,
        "0: one estimate per accepted raw message (lockstep); > 0: newest estimate at this "
        "rate, Hz.",
        0.0,
        10000.0,
        read_only=True,
    ),
    ParameterSpec(
        "diagnostics_period", 1.0, "Period of /diagnostics, wall s.", 0.01, 60.0,
        read_only=True,
    ),
    ParameterSpec(
        "ready_subscribers", 0,
        "Subscriptions /dm/temperature must have matched before 'thermal: ready' (the peers "
        "and recorder that must get the first estimate; the graph sets it).", 0, 64,
        read_only=True,
    ),
    ParameterSpec(
        "time_scale",
        1.0,
        "Multiplier of every slow time (the simulator's shortened scenarios; 1 = physical): "
        "thermal capacitances, sensor_lag_tau, model.adaptation_time; divides "
        "lowpass.cutoff_hz; model noise intensities grow by 1/sqrt(time_scale).",
        1e-4,
        1e4,
        read_only=True,
    ),
    ParameterSpec(
        "sensor_lag_tau", 0.0, "First-order sensor lag compensated by the model, s.", 0.0, 1e4,
        read_only=True,
    ),
    ParameterSpec(
        "lowpass.cutoff_hz", DEFAULT_CUTOFF_HZ, "Low-pass cut-off, Hz.", 1e-5, 1e4,
        read_only=True,
    ),
    ParameterSpec(
        "lowpass.order", DEFAULT_ORDER, "Low-pass filter order (dimensionless).", 1, 8,
        read_only=True,
    ),
    *(
        ParameterSpec(
            f"thermal.{f.name}",
            float(getattr(_NETWORK, f.name)),
            f"Thermal network: {f.name} (capacitances J/K, conductances W/K).",
            0.0,
            1e6,
            read_only=True,
        )
        for f in fields(NetworkParams)
    ),
    ParameterSpec(
        "model.sensor_noise", _TUNING.sensor_noise, "Sensor noise the filter assumes, degC rms.",
        1e-6, 100.0, read_only=True,
    ),
    ParameterSpec(
        "model.process_noise", _TUNING.process_noise,
        "Model error per cell temperature, degC/sqrt(s).", 1e-9, 100.0, read_only=True,
    ),
    ParameterSpec(
        "model.base_drift", _TUNING.base_drift,
        "Random-walk intensity of the unmeasured base plate, degC/sqrt(s).", 1e-9, 100.0,
        read_only=True,
    ),
    ParameterSpec(
        "model.adaptation_time", _TUNING.adaptation_time,
        "Memory of the heat-gain and time-scale error estimates, s (scaled by time_scale).",
        1e-3, 1e7, read_only=True,
    ),
    ParameterSpec(
        "fault.valid_min", _FAULTS.valid_min, "Lowest physical reading, degC.", -273.0, 1000.0,
        read_only=True,
    ),
    ParameterSpec(
        "fault.valid_max", _FAULTS.valid_max, "Highest physical reading, degC.", -273.0, 1000.0,
        read_only=True,
    ),
    ParameterSpec(
        "fault.stuck_time", _FAULTS.stuck_time,
        "A reading unchanged (within stuck_band) this long is stuck, s of sample time.",
        1e-3, 1e7, read_only=True,
    ),
    ParameterSpec(
        "fault.stuck_band", _FAULTS.stuck_band,
        "Peak-to-peak change that still counts as unchanged, degC.", 0.0, 10.0, read_only=True,
    ),
    ParameterSpec(
        "fault.stale_timeout", _FAULTS.stale_timeout,
        "No raw message for this long (wall s) stops the estimates (ERROR).", 1e-3, 1e4,
        read_only=True,
    ),
    ParameterSpec(
        "fault.max_heat_load", _FAULTS.max_heat_load,
        "A /dm/heat_load with a cell above this is rejected (last heat load held), W per cell.",
        1e-6, 1e6, read_only=True,
    ),
    ParameterSpec(
        "fault.heat_load_tolerance", _FAULTS.heat_load_tolerance,
        "Negative heat loads down to minus this pass as rounding; lower ones are rejected, W.",
        0.0, 1e3, read_only=True,
    ),
)


def _stamp(seconds: float) -> Time:
    ns = round(seconds * 1e9)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def config_from_parameters(values: dict[str, object]) -> EstimatorConfig:
    """Build the estimator configuration from declared parameter values.

    Raises:
        ValueError: an inconsistent combination (positions outside the grid, cut-off above
            Nyquist, ...); the message says which.

    """

    def num(name: str) -> float:
        return float(values[name])  # type: ignore[arg-type]

    rows, cols = int(num("rows")), int(num("cols"))
    flat = [float(v) for v in values["sensor_positions"]]  # type: ignore[attr-defined]
    if not flat:
        positions = block_centre_positions(rows, cols, int(num("sensor_pitch")))
    else:
        positions = sensor_positions(rows, cols, flat[0::2], flat[1::2])
    scale = num("time_scale")
    network = NetworkParams(
        **{f.name: num(f"thermal.{f.name}") for f in fields(NetworkParams)}
    ).time_scaled(scale)
    tuning = KalmanTuning(
        sensor_noise=num("model.sensor_noise"),
        process_noise=num("model.process_noise"),
        base_drift=num("model.base_drift"),
        adaptation_time=num("model.adaptation_time"),
    ).time_scaled(scale)
    faults = FaultConfig(
        valid_min=num("fault.valid_min"),
        valid_max=num("fault.valid_max"),
        stuck_time=num("fault.stuck_time"),
        stuck_band=num("fault.stuck_band"),
        stale_timeout=num("fault.stale_timeout"),
        max_heat_load=num("fault.max_heat_load"),
        heat_load_tolerance=num("fault.heat_load_tolerance"),
    )
    return EstimatorConfig(
        rows=rows,
        cols=cols,
        positions=positions,
        kind=str(values["estimator"]),
        sample_period=1.0 / num("sample_rate"),
        lowpass_cutoff_hz=num("lowpass.cutoff_hz") / scale,
        lowpass_order=int(num("lowpass.order")),
        sensor_tau=num("sensor_lag_tau") * scale,
        network=network,
        tuning=tuning,
        faults=faults,
    )


class ThermalNode(Node):
    """Thin ROS wrapper around :class:`TemperatureEstimator` (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        values = declare_parameters(self, SPECS)
        self.config = config_from_parameters(values)
        self.fusion = fusion_from_parameters(
            declare_parameters(self, RESONANCE_SPECS),
            self.config.rows * self.config.cols,
            float(values["time_scale"]),  # type: ignore[arg-type]
        )
        self._sync = (
            None if self.fusion is None else SampleSync(self.fusion, self.config.sample_period)
        )
        self._fused: np.ndarray | None = None  # the newest fused estimate
        started = time.perf_counter()
        self.core = TemperatureEstimator(self.config)
        self.get_logger().info(
            f"{self.config.kind} estimator for {self.config.rows} x {self.config.cols} actuators "
            f"and {self.config.sensor_count} sensors ready in "
            f"{time.perf_counter() - started:.2f} s"
        )
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._raw_watch = StaleWatch(self.config.faults.stale_timeout)
        self._heat_watch = StaleWatch(self.config.faults.stale_timeout)
        self._rejected = {"raw": 0, "heat_load": 0, "resonance": 0, "command": 0}
        self._last_rejection = ""
        self._last_rejection_wall = -np.inf
        self._published = 0
        self._failures = 0  # updates that raised (since start)
        self._last_failure = ""
        self._last_failure_wall = -np.inf
        # Recent update costs and sample intervals, for the estimate diagnostic.
        self._update_seconds: deque[float] = deque(maxlen=_WINDOW)
        self._intervals: deque[float] = deque(maxlen=_WINDOW)
        self._last_arrival: float | None = None
        self._sample_clock = SampleClock(self.config.sample_period)
        self._levels: dict[str, Level] = {}
        # deep publisher history: a recorder that lags for a moment still gets every estimate
        self._pub = self.create_publisher(
            Float64MultiArray, topics.TEMPERATURE, topics.DM_QOS
        )
        self._pub_diag = self.create_publisher(
            DiagnosticArray, topics.DIAGNOSTICS, topics.qos_for(topics.DIAGNOSTICS)
        )
        # Heat load first: the executor serves ready subscriptions in creation order, and the
        # plant publishes a sample's heat load just before its readings, which must use it.
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
        self._ready_subscribers = int(values["ready_subscribers"])  # type: ignore[call-overload]
        self._waiting_for = self._unready()
        self._ready_timer = self.create_timer(0.05, self._check_ready, clock=self._wall)
        period = float(values["diagnostics_period"])  # type: ignore[arg-type]
        self.create_timer(period, self._publish_diagnostics, clock=self._wall)
        rate = float(values["publish_rate"])  # type: ignore[arg-type]
        self._timer_mode = rate > 0.0
        if self._timer_mode:
            self.create_timer(1.0 / rate, self._publish_latest)

    # --- input ------------------------------------------------------------------------------

    def _now(self) -> float:
        return float(self.get_clock().now().nanoseconds) * 1e-9

    def _wall_now(self) -> float:
        return float(self._wall.now().nanoseconds) * 1e-9

    def _reject(self, what: str, reason: str) -> None:
        self._rejected[what] += 1
        self._last_rejection_wall = self._wall_now()
        self._last_rejection = f"{what}: {reason}"
        self.get_logger().warning(
            f"rejected /dm/{'temperature/raw' if what == 'raw' else what} message: "
            f"{reason}",
            throttle_duration_sec=5.0,
        )
        self._publish_if_level_changed()

    def _fail(self, what: str, err: Exception) -> None:
        """Count and report an exception from the core; the estimate restarts afresh."""
        self._failures += 1
        self._last_failure_wall = self._wall_now()
        self._last_failure = f"{what}: {type(err).__name__}: {err}"
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
        self._heat_watch.feed(self._wall_now())

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
        self._raw_watch.feed(self._wall_now())
        now = self._now()
        if self._last_arrival is not None and now > self._last_arrival:
            self._intervals.append(now - self._last_arrival)
        self._last_arrival = now
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
        self._update_seconds.append(time.perf_counter() - started)
        if temperatures is not None and not self._timer_mode:
            self._publish(temperatures)
        self._publish_if_level_changed()

    # --- output -----------------------------------------------------------------------------

    def _publish(self, temperatures: np.ndarray) -> None:
        self._pub.publish(grid_to_msg(temperatures))
        self._published += 1

    def _publish_latest(self) -> None:
        if self._fused is None or self._raw_watch.is_stale(self._wall_now()):
            return
        self._publish(self._fused)

    # --- diagnostics ------------------------------------------------------------------------

    def _sensor_status(self) -> tuple[Level, str, dict[str, object]]:
        latest = self.core.latest
        if not self._raw_watch.seen or latest is None:
            return Level.WARN, "waiting for /dm/temperature/raw", {}
        if self._raw_watch.is_stale(self._wall_now()):
            return (
                Level.ERROR,
                f"no /dm/temperature/raw for more than {self._raw_watch.timeout:g} s: "
                "no estimate published",
                {},
            )
        health = latest.health
        kv: dict[str, object] = {**health.counts(), "sensors": self.config.sensor_count}
        excluded = health.excluded_indices()
        if excluded.size:
            kv["first_excluded"] = ", ".join(str(i) for i in excluded)
        if health.valid_count == 0:
            return Level.ERROR, "no valid sensor: no estimate published", kv
        if excluded.size:
            bad = self.config.sensor_count - health.valid_count
            return Level.WARN, f"{bad} sensor(s) excluded, estimating from the others", kv
        return Level.OK, "all sensors valid", kv

    def _input_status(self) -> tuple[Level, str, dict[str, object]]:
        kv: dict[str, object] = {
            f"rejected_{k}": v
            for k, v in self._rejected.items()
            if self.fusion is not None or k in ("raw", "heat_load")
        }
        if self._last_rejection:
            kv["last_rejection"] = self._last_rejection
        if self._wall_now() - self._last_rejection_wall < _REJECTION_HOLD:
            return Level.WARN, "message(s) of wrong layout, size or value rejected", kv
        if self.config.kind == "model":
            if not self._heat_watch.seen:
                return Level.OK, "no /dm/heat_load received: zero heat load assumed", kv
            if self._heat_watch.is_stale(self._wall_now()):
                return Level.WARN, "/dm/heat_load stale: last heat load held", kv
        return Level.OK, "inputs ok", kv

    def _estimate_status(self) -> tuple[Level, str, dict[str, object]]:
        kv: dict[str, object] = {
            "estimator": self.config.kind,
            "published": self._published,
            "failed_updates": self._failures,
        }
        if self._last_failure:
            kv["last_failure"] = self._last_failure
        if self._update_seconds:
            kv["update_ms_mean"] = 1e3 * float(np.mean(self._update_seconds))
            kv["update_ms_median"] = 1e3 * float(np.median(self._update_seconds))
            kv["update_ms_max"] = 1e3 * float(np.max(self._update_seconds))
        model = self.core.model
        if model is not None and model.initialised:
            kv["base_plate_degc"] = model.base_temperature
            kv.update({f"model_error_{k}": v for k, v in model.biases.items()})
        if self._fused is not None:
            kv["min_degc"] = float(np.min(self._fused))
            kv["max_degc"] = float(np.max(self._fused))
        level, message = Level.OK, "estimating"
        if self._wall_now() - self._last_failure_wall < _REJECTION_HOLD:
            return Level.ERROR, "an update failed: estimate restarted from the readings", kv
        if self._intervals:
            interval = float(np.median(self._intervals))
            kv["sample_interval_s"] = interval
            expected = self.config.sample_period
            if abs(interval - expected) > _RATE_TOLERANCE * expected:
                level = Level.WARN
                message = (
                    f"samples arrive every {interval:.4g} s, filters are built for "
                    f"{expected:.4g} s (set sample_rate)"
                )
        return level, message, kv

    def _selfsensing_status(self) -> tuple[Level, str, dict[str, object]]:
        assert self._sync is not None and self.fusion is not None
        sync = self._sync
        if sync.last_sweep is None or sync.health is None:
            return Level.WARN, "waiting for /dm/resonance: model estimate alone", {}
        kv: dict[str, object] = {
            **sync.health.counts(),
            **sync.health.worst(),
            **{f"sweeps_{k}": v for k, v in sync.paired.items()},
        }
        quiet = self._now() - sync.last_sweep
        if quiet > self.fusion.config.stale_after:
            return Level.WARN, f"no /dm/resonance for {quiet:.3g} s: model estimate alone", kv
        health = sync.health
        dropped = int(np.count_nonzero(health.implausible | health.stale | health.stuck))
        if dropped:
            return (
                Level.WARN,
                f"{dropped} resonance channel(s) dropped (implausible, stuck or stale)",
                kv,
            )
        return Level.OK, "resonance readings fused", kv

    def _unready(self) -> list[str]:
        """Return what readiness still waits for: the raw input, the estimates' subscribers."""
        return [*unmatched([self._raw_sub]), *unreached(self._pub, self._ready_subscribers)]

    def _check_ready(self) -> None:
        """Follow the raw input's and the output's matching until ready; say so at once."""
        waiting = self._unready()
        if waiting != self._waiting_for:
            self._waiting_for = waiting
            self._publish_diagnostics()
        if not waiting:
            self._ready_timer.cancel()

    def _statuses(self) -> list[DiagnosticStatus]:
        out = [readiness_status(self.get_name(), self._waiting_for)]
        aspects = [
            ("sensors", self._sensor_status),
            ("input", self._input_status),
            ("estimate", self._estimate_status),
        ]
        if self.fusion is not None:
            aspects.append(("self-sensing", self._selfsensing_status))
        for aspect, build in aspects:
            level, message, kv = build()
            self._levels[aspect] = level
            out.append(make_status(f"{self.get_name()}: {aspect}", level, message, kv))
        return out

    def _publish_if_level_changed(self) -> None:
        current = {"sensors": self._sensor_status()[0], "input": self._input_status()[0]}
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
        ThermalNode, args, help_text=usage_text("es_thermal thermal_node", __doc__ or "", SPECS)
    )


if __name__ == "__main__":
    raise SystemExit(main())
