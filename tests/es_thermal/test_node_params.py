"""es_thermal.node_params: the thermal node's parameters -> estimator configuration."""

from __future__ import annotations

import numpy as np
import pytest

from es_node_runtime.errors import ParameterTypeError
from es_thermal.kalman import KalmanTuning
from es_thermal.node_params import SPECS, config_from_parameters


def values(**changes: object) -> dict[str, object]:
    out: dict[str, object] = {spec.name: spec.default for spec in SPECS}
    out.update(changes)
    return out


def test_the_defaults_give_one_sensor_per_actuator() -> None:
    config = config_from_parameters(values(rows=3, cols=4))
    assert (config.rows, config.cols, config.sensor_count) == (3, 4, 12)
    assert config.kind == "model" and config.sample_period == pytest.approx(0.1)


def test_time_scale_shortens_every_slow_time() -> None:
    base = config_from_parameters(values(sensor_lag_tau=2.0))
    scaled = config_from_parameters(values(sensor_lag_tau=2.0, time_scale=0.05))
    assert scaled.sensor_tau == pytest.approx(0.05 * base.sensor_tau)
    assert scaled.lowpass_cutoff_hz == pytest.approx(base.lowpass_cutoff_hz / 0.05)


def test_explicit_positions_and_the_pitch() -> None:
    given = config_from_parameters(values(rows=4, cols=4, sensor_positions=[0.5, 0.5, 2.0, 3.0]))
    assert given.sensor_count == 2
    assert config_from_parameters(values(rows=4, cols=4, sensor_pitch=2)).sensor_count == 4


def test_bad_values_raise_readable_errors() -> None:
    with pytest.raises(ValueError, match=r"[Pp]osition|outside|grid"):
        config_from_parameters(values(rows=2, cols=2, sensor_positions=[5.0, 5.0]))
    with pytest.raises(ParameterTypeError, match="sample_rate"):
        config_from_parameters(values(sample_rate="fast"))
    by_name = {spec.name: spec for spec in SPECS}
    assert by_name["sensor_positions"].reason_to_reject([1.0, 2.0, 3.0]) is not None
    assert by_name["sensor_positions"].reason_to_reject(["a", "b"]) is not None
    assert by_name["sensor_positions"].reason_to_reject([1.0, 2.0]) is None


def test_sensor_lag_one_value_or_one_per_sensor() -> None:
    # The scalar stays what it was (backward compatible); a list gives one lag per sensor.
    scalar = config_from_parameters(values(rows=2, cols=2, sensor_lag_tau=2.0, time_scale=0.5))
    assert float(scalar.sensor_tau) == pytest.approx(1.0)
    listed = config_from_parameters(
        values(rows=2, cols=2, sensor_lag_tau=[1.0, 2.0, 3.0, 4.0], time_scale=0.5)
    )
    assert np.ravel(listed.sensor_tau).tolist() == pytest.approx([0.5, 1.0, 1.5, 2.0])
    with pytest.raises(ValueError, match="one per sensor"):
        config_from_parameters(values(rows=2, cols=2, sensor_lag_tau=[1.0, 2.0]))


def test_sensor_offsets_and_their_uncertainty() -> None:
    config = config_from_parameters(
        values(rows=1, cols=2, sensor_offsets=[0.1, -0.2], sensor_offsets_sd=0.05)
    )
    assert np.ravel(config.sensor_offsets).tolist() == pytest.approx([0.1, -0.2])
    assert float(config.sensor_offset_sd) == pytest.approx(0.05)
    by_name = {spec.name: spec for spec in SPECS}
    for name in ("sensor_lag_tau", "sensor_offsets", "sensor_offsets_sd"):
        spec = by_name[name]
        assert spec.dynamic_typing and spec.reason_to_reject([0.0, 0.5]) is None
        assert spec.reason_to_reject(["a"]) is not None
        assert spec.reason_to_reject([1e9]) is not None
    assert by_name["sensor_lag_tau"].reason_to_reject([-1.0]) is not None
    assert by_name["sensor_offsets_sd"].reason_to_reject(-0.1) is not None


def test_stage_step_gain_is_off_by_default() -> None:
    assert config_from_parameters(values()).tuning.step_gate == 0.0
    scaled = config_from_parameters(values(**{"model.step_gate": 4.0, "time_scale": 0.04}))
    assert scaled.tuning.step_gate == 4.0
    assert scaled.tuning.step_size == KalmanTuning().step_size  # a temperature: not scaled
