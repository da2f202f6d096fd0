"""The thermal node's health: what came in, what was rejected or failed, and its diagnostics.

Pure (no rclpy): :class:`NodeHealth` counts rejected messages and failed updates, follows
the staleness of the raw readings and the heat load and the timing of the updates, and
builds the node's diagnostic aspects (sensors, input, estimate, self-sensing) as
(level, message, key/values) rows. The node feeds it events with their wall or sample time.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from es_common.arrays import FloatArray
from es_msgs_py.diagnostics import Level
from es_thermal.estimator import Estimate, EstimatorConfig
from es_thermal.faults import StaleWatch
from es_thermal.kalman import ModelEstimator
from es_thermal.network import per_sensor
from es_thermal.sweep_sync import SampleSync

__all__ = ["REJECTION_HOLD", "NodeHealth", "Row"]

#: One diagnostic aspect: (level, message, key/values).
Row = tuple[Level, str, dict[str, object]]
#: Measured sample intervals this far off the configured ``sample_rate`` give a WARN.
_RATE_TOLERANCE = 0.25
#: A rejected message keeps the input diagnostic at WARN (a failed update the estimate
#: diagnostic at ERROR) this long [wall s].
REJECTION_HOLD = 5.0
#: Updates the estimate diagnostic's timing and rate figures cover.
_WINDOW = 200


class NodeHealth:
    """Counts, staleness and timing of the thermal node's inputs and updates."""

    def __init__(self, config: EstimatorConfig, selfsensing: bool) -> None:
        """Start with nothing seen.

        Args:
            config: the estimator's configuration (sensor count, sample period, kind and
                the stale timeout).
            selfsensing: whether /dm/resonance and /dm/command are inputs too.

        """
        self.config = config
        self.selfsensing = selfsensing
        #: The largest 1-sigma offset uncertainty of a sensor [degC] (0: none given).
        self._offset_sd_max = float(
            np.max(per_sensor(config.sensor_offset_sd, config.sensor_count, "sensor offset sd"))
        )
        self.raw_watch = StaleWatch(config.faults.stale_timeout)
        self.heat_watch = StaleWatch(config.faults.stale_timeout)
        self.rejected_counts = {"raw": 0, "heat_load": 0, "resonance": 0, "command": 0}
        self._last_rejection = ""
        self._last_rejection_wall = -np.inf
        self.published = 0
        self._failures = 0
        self._last_failure = ""
        self._last_failure_wall = -np.inf
        self._update_seconds: deque[float] = deque(maxlen=_WINDOW)
        self._intervals: deque[float] = deque(maxlen=_WINDOW)
        self._last_arrival: float | None = None

    def rejected(self, what: str, reason: str, wall: float) -> None:
        """Count a rejected message of input ``what`` (raw, heat_load, resonance, command)."""
        self.rejected_counts[what] += 1
        self._last_rejection_wall = wall
        self._last_rejection = f"{what}: {reason}"

    def failed(self, what: str, err: Exception, wall: float) -> None:
        """Count an exception from the estimator (``what`` failed: update, heat load, ...)."""
        self._failures += 1
        self._last_failure_wall = wall
        self._last_failure = f"{what}: {type(err).__name__}: {err}"

    def arrived(self, now: float) -> None:
        """Note the arrival of raw readings at sample time ``now`` [s] (the rate check)."""
        if self._last_arrival is not None and now > self._last_arrival:
            self._intervals.append(now - self._last_arrival)
        self._last_arrival = now

    def updated(self, seconds: float) -> None:
        """Note the cost of one successful update [s of wall time]."""
        self._update_seconds.append(seconds)

    def sensor_status(self, latest: Estimate | None, wall: float) -> Row:
        """Return the sensors' aspect: waiting, stale (ERROR), excluded sensors, all valid."""
        if not self.raw_watch.seen or latest is None:
            return Level.WARN, "waiting for /dm/temperature/raw", {}
        if self.raw_watch.is_stale(wall):
            return (
                Level.ERROR,
                f"no /dm/temperature/raw for more than {self.raw_watch.timeout:g} s: "
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

    def input_status(self, wall: float) -> Row:
        """Return the inputs' aspect: rejected messages (WARN a while), heat load stale."""
        kv: dict[str, object] = {
            f"rejected_{k}": v
            for k, v in self.rejected_counts.items()
            if self.selfsensing or k in ("raw", "heat_load")
        }
        if self._last_rejection:
            kv["last_rejection"] = self._last_rejection
        if wall - self._last_rejection_wall < REJECTION_HOLD:
            return Level.WARN, "message(s) of wrong layout, size or value rejected", kv
        if self.config.kind == "model":
            if not self.heat_watch.seen:
                return Level.OK, "no /dm/heat_load received: zero heat load assumed", kv
            if self.heat_watch.is_stale(wall):
                return Level.WARN, "/dm/heat_load stale: last heat load held", kv
        return Level.OK, "inputs ok", kv

    def estimate_status(
        self, model: ModelEstimator | None, fused: FloatArray | None, wall: float
    ) -> Row:
        """Return the estimate's aspect: failures (ERROR a while), timing, sample rate."""
        kv: dict[str, object] = {
            "estimator": self.config.kind,
            "published": self.published,
            "failed_updates": self._failures,
        }
        if self._last_failure:
            kv["last_failure"] = self._last_failure
        if self._update_seconds:
            kv["update_ms_mean"] = 1e3 * float(np.mean(self._update_seconds))
            kv["update_ms_median"] = 1e3 * float(np.median(self._update_seconds))
            kv["update_ms_max"] = 1e3 * float(np.max(self._update_seconds))
        if self._offset_sd_max > 0.0:  # a constant error no filter can remove
            kv["sensor_offset_sd_max_degc"] = self._offset_sd_max
        if model is not None and model.initialised:
            kv["base_plate_degc"] = model.base_temperature
            kv["following_stage_step"] = model.following_step
            kv.update({f"model_error_{k}": v for k, v in model.biases.items()})
        if fused is not None:
            kv["min_degc"] = float(np.min(fused))
            kv["max_degc"] = float(np.max(fused))
        level, message = Level.OK, "estimating"
        if wall - self._last_failure_wall < REJECTION_HOLD:
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

    def selfsensing_status(self, sync: SampleSync, now: float) -> Row:
        """Return the self-sensing aspect: waiting, stale sweeps, dropped channels, fused."""
        if sync.last_sweep is None or sync.health is None:
            return Level.WARN, "waiting for /dm/resonance: model estimate alone", {}
        kv: dict[str, object] = {
            **sync.health.counts(),
            **sync.health.worst(),
            **{f"sweeps_{k}": v for k, v in sync.paired.items()},
        }
        quiet = now - sync.last_sweep
        if quiet > sync.fusion.config.stale_after:
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

