"""es_thermal.node_health: the thermal node's fault and readiness aspects, without DDS."""

from __future__ import annotations

import numpy as np

from es_msgs_py.diagnostics import Level
from es_thermal.estimator import TemperatureEstimator
from es_thermal.node_health import REJECTION_HOLD, NodeHealth
from es_thermal.node_params import SPECS, config_from_parameters


def setup(**changes: object) -> tuple[NodeHealth, TemperatureEstimator]:
    values: dict[str, object] = {spec.name: spec.default for spec in SPECS}
    values.update({"rows": 2, "cols": 2, **changes})
    config = config_from_parameters(values)
    return NodeHealth(config, selfsensing=False), TemperatureEstimator(config)


def test_sensors_wait_then_report_valid_excluded_and_stale_readings() -> None:
    health, core = setup()
    assert health.sensor_status(core.latest, 0.0)[:2] == (
        Level.WARN, "waiting for /dm/temperature/raw"
    )  # fmt: skip
    health.raw_watch.feed(0.0)
    core.update(0.0, np.full(4, 40.0))
    assert health.sensor_status(core.latest, 0.1)[0] is Level.OK
    core.update(0.1, np.array([40.0, np.nan, 40.0, 40.0]))
    level, message, kv = health.sensor_status(core.latest, 0.2)
    assert level is Level.WARN and message.startswith("1 sensor(s) excluded")
    assert kv["first_excluded"] == "1"
    core.update(0.2, np.full(4, np.nan))
    assert health.sensor_status(core.latest, 0.3)[:2] == (
        Level.ERROR, "no valid sensor: no estimate published"
    )  # fmt: skip
    stale = health.config.faults.stale_timeout
    assert health.sensor_status(core.latest, stale + 0.1)[0] is Level.ERROR


def test_a_rejected_message_warns_for_a_while_and_is_counted() -> None:
    health, _ = setup()
    assert health.input_status(0.0)[:2] == (
        Level.OK, "no /dm/heat_load received: zero heat load assumed"
    )  # fmt: skip
    health.rejected("raw", "wrong size", 10.0)
    level, _, kv = health.input_status(10.0 + REJECTION_HOLD / 2)
    assert level is Level.WARN and kv["rejected_raw"] == 1
    assert kv["last_rejection"] == "raw: wrong size" and "rejected_resonance" not in kv
    later = 10.0 + REJECTION_HOLD + 0.1
    health.heat_watch.feed(later)
    assert health.input_status(later)[0] is Level.OK
    stale = health.config.faults.stale_timeout
    assert health.input_status(later + stale + 0.1)[:2] == (
        Level.WARN, "/dm/heat_load stale: last heat load held"
    )  # fmt: skip


def test_a_failed_update_is_an_error_for_a_while() -> None:
    health, core = setup()
    health.failed("update", ZeroDivisionError("boom"), 3.0)
    level, message, kv = health.estimate_status(core.model, None, 3.5)
    assert level is Level.ERROR and "failed" in message
    assert kv["failed_updates"] == 1 and kv["last_failure"] == "update: ZeroDivisionError: boom"
    assert health.estimate_status(core.model, None, 3.0 + REJECTION_HOLD + 0.1)[0] is Level.OK


def test_samples_off_the_configured_rate_warn() -> None:
    health, core = setup(sample_rate=10.0)
    for k in range(5):
        health.arrived(0.1 * k)
        health.updated(1e-3)
    level, _, kv = health.estimate_status(core.model, np.full((2, 2), 40.0), 0.0)
    assert level is Level.OK and kv["sample_interval_s"] == 0.1 and kv["max_degc"] == 40.0
    slow, _ = setup(sample_rate=10.0)
    for k in range(5):
        slow.arrived(0.5 * k)
    level, message, _ = slow.estimate_status(core.model, None, 0.0)
    assert level is Level.WARN and "set sample_rate" in message
