"""The calibration-loop benchmark's split of the error into steady state and after stage steps.

The steady-state RMS the benchmark reports (issue 38) must leave out exactly the settling
window after each stage step and keep a ramp whole.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_calibration_loop.py"


def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_calibration_loop", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


bench = _bench()


def test_the_window_after_each_stage_step_is_not_steady_state() -> None:
    time = np.arange(0.0, 10.0, 0.5)
    base = np.where(time < 3.0, 40.0, np.where(time < 7.0, 42.0, 44.0))
    settled = bench.settled_mask(base, time, settle_s=1.0)
    # steps at t = 3.0 and t = 7.0: 3.0, 3.5 and 7.0, 7.5 are within 1 s, the rest settled
    unsettled_times = time[~settled]
    np.testing.assert_allclose(unsettled_times, [3.0, 3.5, 7.0, 7.5])


def test_a_ramp_is_steady_state_throughout() -> None:
    time = np.arange(0.0, 10.0, 0.1)
    base = 41.0 + time  # 0.1 degC per step, below the step threshold
    assert bench.settled_mask(base, time, settle_s=5.0).all()
