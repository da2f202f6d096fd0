"""The search's caches and compiled low-pass change no result (issue 39).

Candidate-independent work (play passes of the NNLS screening, drive signals and their
low-passes per time constant and rows) is cached per recording (model/cache.py), and the
low-pass and self-heating's drive signal run in compiled loops (model/lowpass_loop.py,
model/heating_loop.py). Here the whole effect search runs
on a small independent stand record (testing/standgen) once as the calibration runs it and
once with every cache bypassed and the numpy low-pass: the accepted effects, their
parameters and the fit's numbers must be the same. The discovery library's low-passes, the
pooled grams of the normal equations (one BLAS product) and the tool's one BLAS thread are
checked the same way, against their plain definitions.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from standgen import StandConfig, simulate
from standgen.effects import Effects, Hysteresis, SelfHeating

from es_calibration.data.align import align
from es_calibration.discovery.library import Library, Rows
from es_calibration.model import cache
from es_calibration.model.cache import BoundedCache
from es_calibration.model.composite import CompositeModel
from es_calibration.model.fit import pooled_gram
from es_calibration.model.history import DriveHistory, first_order_lowpass, lowpass_at
from es_calibration.search.blockdelay import _Scan
from es_calibration.search.selection import search_effects
from es_calibration.search.state import (
    Workspace,
    base_state,
    choose_stamp_convention,
    extend_global,
    extend_local,
)
from es_feedforward.kernels import KERNELS_ENV
from es_physics.effects import get

from .stand_data import measured

CANDIDATES = ("hysteresis", "self_heating", "frequency_dispersion")
_tanh = np.tanh


def _search(monkeypatch: pytest.MonkeyPatch, backend: str):
    monkeypatch.setenv(KERNELS_ENV, backend)
    config = StandConfig(
        rows=2,
        cols=2,
        rate_hz=250.0,
        duration_s=24.0,
        temperature_kind="grid",
        noise_m=0.4e-9,
        effects=Effects(
            hysteresis=Hysteresis((30.0,), (0.04,)),
            self_heating=SelfHeating(gain=2.5e-5, tau_s=0.76),
        ),
        seed=11,
    )
    aligned = choose_stamp_convention(align(measured(simulate(config))))
    ws = Workspace(aligned, np.arange(aligned.n_actuators, dtype=np.intp), (2, 2))
    final, added, _ = search_effects(ws, base_state(ws), CANDIDATES)
    return final, [name for name, _, _ in added]


def test_the_search_finds_the_same_effects_and_numbers_with_and_without_the_caches(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    hits = []
    original = BoundedCache.get

    def counted(self: BoundedCache, key: object) -> object:
        found = original(self, key)
        hits.append(found is not None)
        return found

    monkeypatch.setattr(BoundedCache, "get", counted)
    cached, cached_added = _search(monkeypatch, "fused")
    assert "es_calibration.model.lowpass_loop" in sys.modules  # the compiled low-pass ran
    assert sum(hits) > 0  # the caches served something
    hits.clear()
    with cache.bypassed():
        plain, plain_added = _search(monkeypatch, "numpy")
    assert not any(hits)
    assert "self_heating" in cached.model.effects  # a low-pass effect was fitted and kept
    assert cached_added == plain_added
    assert cached.model.effects == plain.model.effects
    assert cached.thresholds == plain.thresholds
    assert cached.delay_s == plain.delay_s
    # deterministic: the same numbers, not only within their 1-sigma
    np.testing.assert_array_equal(cached.fit.glob, plain.fit.glob)
    np.testing.assert_array_equal(cached.fit.local, plain.fit.local)
    assert cached.heldout_sse == plain.heldout_sse


@pytest.mark.parametrize("tau", [1e-4, 0.05, 3.0, 1e30])
def test_the_compiled_lowpass_gives_numpys_numbers(
    monkeypatch: pytest.MonkeyPatch, tau: float
) -> None:
    rng = np.random.default_rng(4)
    x = np.cumsum(rng.normal(0.0, 3.0, (900, 5)), axis=0)
    rows = np.array([0, 1, 2, 17, 450, 899])
    period = 0.002
    y, slope = first_order_lowpass(x, period, tau)
    for backend in ("numpy", "fused"):
        monkeypatch.setenv(KERNELS_ENV, backend)
        got_y, got_slope = lowpass_at(x, period, tau, rows)
        np.testing.assert_array_equal(got_y, y[rows])
        np.testing.assert_array_equal(got_slope, slope[rows])
        got_y, got_slope = lowpass_at(x, period, tau, rows, with_slope=False)
        np.testing.assert_array_equal(got_y, y[rows])
        assert not got_slope.any()
    assert "es_calibration.model.lowpass_loop" in sys.modules


@pytest.mark.parametrize("log_window", [float(np.log(1.6)), float(np.log(0.2)), 9.0])
def test_the_compiled_heating_signal_gives_numpys_numbers(
    monkeypatch: pytest.MonkeyPatch, log_window: float
) -> None:
    # 9.0: a window beyond the range, held at its bound (the slope is zero)
    rng = np.random.default_rng(5)
    command = np.cumsum(rng.normal(0.0, 3.0, (1200, 6)), axis=0)
    command[300:340] = command[300]  # a held command: level and swing of zero
    effect = get("self_heating")
    period = 0.002
    signal = effect.drive_signal(command, period, (log_window,))
    (slope,) = effect.drive_signal_slopes(command, period, (log_window,))
    for backend in ("numpy", "fused"):
        monkeypatch.setenv(KERNELS_ENV, backend)
        with cache.bypassed():
            history = DriveHistory(command, period)
            np.testing.assert_array_equal(history.signal(effect, (log_window,)), signal)
            (got,) = history.signal_slopes(effect, (log_window,))
            np.testing.assert_array_equal(got, slope)
    assert "es_calibration.model.heating_loop" in sys.modules
    assert (log_window == 9.0) == (not slope.any())


def test_the_discovery_librarys_lowpasses_at_rows_equal_the_full_rate_numpy_filter(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    config = StandConfig(
        rows=2, cols=2, rate_hz=250.0, duration_s=6.0, temperature_kind="grid", noise_m=0.4e-9,
        seed=3,
    )
    aligned = choose_stamp_convention(align(measured(simulate(config))))
    rows = np.sort(np.random.default_rng(6).choice(aligned.t.size, 300, replace=False))
    blank = np.zeros((aligned.n_actuators, rows.size))
    at = Rows(rows, blank, blank, blank, blank)
    command = np.nan_to_num(aligned.command)
    ci = np.maximum(aligned.command_index(rows, 0.0), 0)
    for backend in ("numpy", "fused"):
        monkeypatch.setenv(KERNELS_ENV, backend)
        library = Library(aligned, (2, 2))
        keys = [(code, tau) for code in (10, 11) for tau in library.taus]
        got = library.signals(at, keys)
        for code, tau in keys:
            x = command if code == 10 else command**2
            full, _ = first_order_lowpass(x, aligned.command_period, tau)
            np.testing.assert_array_equal(got[(code, tau)], full[ci].T)


#: Models whose law evaluation both paths must agree on: every stage of the composite model
#: (lead, heating per actuator, play, relaxation, curved law, gain, coupling, additive).
MODELS = [
    ((), ()),
    (("temperature_curvature", "drift", "coupling"), ()),
    (("sensor_lag", "hysteresis", "thermal_expansion"), ()),
    (("self_heating", "frequency_dispersion", "temperature_curvature"), ("self_heating.gain",)),
    (("sensor_lag", "self_heating", "hysteresis", "drift", "coupling"), ()),
]


@pytest.mark.parametrize(("effects", "per_actuator"), MODELS)
def test_the_compiled_law_gives_numpys_numbers(
    monkeypatch: pytest.MonkeyPatch, effects: tuple[str, ...], per_actuator: tuple[str, ...]
) -> None:
    config = StandConfig(rows=2, cols=3, rate_hz=250.0, duration_s=12.0,
                         temperature_kind="grid", noise_m=0.4e-9, seed=3)
    aligned = choose_stamp_convention(align(measured(simulate(config))))
    ws = Workspace(aligned, np.arange(aligned.n_actuators, dtype=np.intp), (2, 3))
    base = base_state(ws)
    model = CompositeModel(effects, operators=2, per_actuator=per_actuator)
    rng = np.random.default_rng(8)
    local = extend_local(base, model)
    local[:, 4:] += rng.normal(0.0, 1e-3, (local.shape[0], local.shape[1] - 4))
    starts = {f"{e}.{k}": v for e in effects for k, v in get(e).starts(12.0)[0].items()}
    glob = extend_global(base, model, starts)
    glob += rng.normal(0.0, 0.01, glob.size)  # away from any start's zeros
    thresholds = (0.5, 2.0) if model.play else None
    data, _ = ws.input_pair(0.0013, thresholds)
    results = {}
    for backend in ("numpy", "fused"):
        monkeypatch.setenv(KERNELS_ENV, backend)
        with cache.bypassed():  # each path computes its own tanh
            results[backend] = (model.evaluate(local, glob, data),
                                model.evaluate(local, glob, data, jacobian=False))
    assert "es_calibration.model.law_loop" in sys.modules
    # the trial point's tanh reused by the same point's Jacobian evaluation (and only there)
    monkeypatch.setenv(KERNELS_ENV, "fused")
    calls = []

    def counted_tanh(x: np.ndarray, *args: object, **kwargs: object) -> np.ndarray:
        calls.append(1)
        return _tanh(x, *args, **kwargs)  # type: ignore[call-overload]

    monkeypatch.setattr(np, "tanh", counted_tanh)
    trial = model.evaluate(local, glob, data, jacobian=False)
    again = model.evaluate(local, glob, data)
    moved = local.copy()
    moved[:, 2] *= 1.0 + 1e-9
    model.evaluate(moved, glob, data, jacobian=False)
    assert len(calls) == 2
    np.testing.assert_array_equal(trial.prediction, results["numpy"][0].prediction)
    np.testing.assert_array_equal(again.jac_local, results["numpy"][0].jac_local)
    np.testing.assert_array_equal(again.jac_global, results["numpy"][0].jac_global)
    (plain, plain_value), (fused, fused_value) = results["numpy"], results["fused"]
    assert np.isfinite(plain.prediction).all() and plain.jac_local.any()
    np.testing.assert_array_equal(fused.prediction, plain.prediction)
    np.testing.assert_array_equal(fused.jac_local, plain.jac_local)
    np.testing.assert_array_equal(fused.jac_global, plain.jac_global)
    np.testing.assert_array_equal(fused_value.prediction, plain.prediction)
    np.testing.assert_array_equal(plain_value.prediction, plain.prediction)


@pytest.mark.parametrize("shift", [0.0, 0.3, 1.75, 12.05])
def test_the_compiled_block_delay_interpolation_gives_numpys_numbers(
    monkeypatch: pytest.MonkeyPatch, shift: float
) -> None:
    config = StandConfig(rows=2, cols=2, rate_hz=250.0, duration_s=8.0,
                         temperature_kind="grid", noise_m=0.4e-9, seed=6)
    scan = _Scan(choose_stamp_convention(align(measured(simulate(config)))))
    rows = np.arange(0, scan.ws.aligned.t.size, 3)
    got = {}
    for backend in ("numpy", "fused"):
        monkeypatch.setenv(KERNELS_ENV, backend)
        got[backend] = scan.inputs(rows, shift)
    assert "es_calibration.search.interp_loop" in sys.modules
    assert got["numpy"].valid.sum() > rows.size  # most samples usable
    np.testing.assert_array_equal(got["fused"].voltage, got["numpy"].voltage)
    np.testing.assert_array_equal(got["fused"].valid, got["numpy"].valid)
    np.testing.assert_array_equal(got["fused"].displacement, got["numpy"].displacement)


def test_a_bounded_cache_keeps_its_budget_and_evicts_the_least_recently_used() -> None:
    store: BoundedCache[np.ndarray] = BoundedCache(budget_bytes=3 * 800)
    for i in range(3):
        store.put(i, np.zeros(100))
    assert store.get(0) is not None  # 0 is now the most recently used
    store.put(3, np.zeros(100))
    assert store.get(1) is None and store.get(0) is not None and store.get(3) is not None
    assert store.nbytes == 3 * 800
    store.put(4, np.zeros(1000))  # larger than the whole budget: returned, not kept
    assert store.get(4) is None and store.nbytes == 3 * 800
    with cache.bypassed():
        assert store.get(0) is None
        store.put(5, np.zeros(1))
    assert store.get(5) is None and store.get(0) is not None


def test_a_kept_value_cannot_be_written_into() -> None:
    store: BoundedCache[tuple[np.ndarray, np.ndarray]] = BoundedCache()
    kept = store.put("k", (np.zeros(3), np.ones(2)))
    for array in kept:
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 5.0
    assert store.get("k")[0].tolist() == [0.0, 0.0, 0.0]  # type: ignore[index]



def test_the_pooled_gram_is_the_einsum_of_its_definition() -> None:
    # one BLAS product over the (actuator, sample) pairs: the sums of np.einsum's definition
    # up to their order's rounding (the LM's global normal equations, the play screening's)
    rng = np.random.default_rng(12)
    for shape in ((7, 300, 3), (4, 120, 28), (3, 50, 0)):
        columns = rng.normal(size=shape) * rng.uniform(1e-12, 1e3, shape[-1])
        resid = rng.normal(size=shape[:2]) * 1e-9
        gram, rhs = pooled_gram(columns, resid)
        np.testing.assert_allclose(gram, np.einsum("anp,anq->pq", columns, columns),
                                   rtol=1e-12, atol=0.0)
        np.testing.assert_allclose(rhs, np.einsum("anp,an->p", columns, resid),
                                   rtol=1e-12, atol=1e-300)
        assert gram.shape == (shape[-1], shape[-1]) and rhs.shape == (shape[-1],)


def test_the_calibrate_tool_runs_one_blas_thread_unless_told_otherwise() -> None:
    code = "import os, es_calibration.calibrate; print(os.environ['OPENBLAS_NUM_THREADS'])"
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    for given, expected in ((None, "1"), ("2", "2")):
        run_env = env if given is None else {**env, "OPENBLAS_NUM_THREADS": given}
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              check=False, timeout=120, env=run_env)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.strip() == expected
