"""Benchmark of the feedforward kernels: time per call and ratio to one ``np.sqrt`` (the floor).

Usage (from the repository root, after ./scripts/bootstrap)::

    .venv/bin/python bench/bench_kernels.py [--sizes 1,144,1024,4096,16384]

For each grid size N (a near-square R x C grid with per-actuator parameter maps, set points in
0-150 nm, temperatures in 40-52 degC) it times:

- ``laws+inverse_hyperbolic``: temperature laws and hyperbolic inverse together
  (``CompiledLaws.hyperbolic_inverse(z, T)``), the issue-3 figure;
- ``inverse_hyperbolic`` ... ``uncompensated``: ``Feedforward.command(z, t)`` of each mode
  with the temperature already taken (what the node pays per set point);
- ``observer_10hz`` and ``observer_jumps``: the observer is iterative and stops once the
  next update would move nothing by more than ``observer.tolerance``, so its cost depends on
  how far the set point moves. ``observer`` holds one set point (the other modes' workload:
  no update runs), ``observer_10hz`` follows a 10 Hz sine over 0-150 nm at 2 kHz with a
  phase per actuator (a smooth trajectory: two or three updates), ``observer_jumps`` takes a
  new random set point every call (the worst case: every update up to ``observer.iterations``);
- ``observer_10hz_floor`` and ``observer_jumps_floor``: the least arithmetic the observer's
  updates (the model's tanh, the error over the local gain) need on numpy's SIMD functions
  for the same set points, each with its own number of updates (a sqrt, a tanh per update, a
  divide per step and one for the model error; :func:`_observer_arithmetic`): how close the
  observer is to its floor, and whether the 10x target can be met on that workload at all;
- ``observer_numpy`` (``--numpy-too``): the observer on the pure-numpy path
  (``kernels.Backend.NUMPY``) beside the default (fused when numba is importable; see
  ``ES_DM_FEEDFORWARD_KERNELS`` in :mod:`es_feedforward.kernels`);
- ``discovered_none_10hz``, ``discovered_output_10hz`` and ``discovered_drive_10hz``: the
  hyperbolic inverse following the 10 Hz sine at 2 kHz (time advancing, so rates are real)
  without a discovered term, with an output-side one (a low-pass of V^2, undone from the set
  point) and with a drive-side one (an amplifier droop with the commands' rate, solved by
  the fixed-point inverse of the augmented law, up to ``FIXED_POINT_STEPS`` steps of the
  terms over the grid);
- ``update_temperature``: ``Feedforward.update_temperature`` (once per temperature message).

Each figure is the best of several repeats of this thread's CPU time (so other processes on
the machine do not inflate it), and the np.sqrt floor is measured next to it in the same
repeat.
:func:`bench_kernels` returns the rows for a benchmark suite; ``main`` prints a table.
"""

from __future__ import annotations

import argparse
import itertools
import time
import timeit
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np

from es_feedforward.compensation import CompensationParams
from es_feedforward.feedforward import Feedforward, FeedforwardConfig, Mode
from es_feedforward.kernels import Backend, observer_command
from es_physics.effects.discovered import Carrier, Term, values_from_terms
from es_physics.laws import DEFAULT_V_LIMIT, CompiledLaws
from es_physics.params import ActuatorParams

DEFAULT_SIZES = (1, 144, 1024, 4096, 16384)
#: Ends the name of a row that is a floor of the row it extends (its arithmetic alone).
FLOOR_SUFFIX = "_floor"
#: CPU time of this thread: time the process waits for a core (other load) does not count.
CPU_TIMER = time.thread_time
#: Set-point period of the moving workloads [s] (2 kHz).
FRAME_PERIOD = 1.0 / 2000.0
#: Discovered terms of the compensation kernels: an output-side low-pass of V^2 [m/V^2,
#: tau 0.4 s] and a drive-side amplifier droop [V/(V V/s)] that stops growing at 4 kV/s.
DISCOVERED = {
    "output": Term(2e-13, (11, 0.4)),
    "drive": Term(-1.2e-5, (1, 0.0), (15, 4000.0), Carrier.DRIVE),
}


@dataclass(frozen=True)
class KernelTiming:
    """One benchmark row."""

    kernel: str
    size: int
    seconds_per_call: float
    sqrt_seconds_per_call: float

    @property
    def ratio_to_sqrt(self) -> float:
        """Time per call divided by the time of one np.sqrt over the same number of elements."""
        return self.seconds_per_call / self.sqrt_seconds_per_call


def grid_shape(size: int) -> tuple[int, int]:
    """Return the most square R x C with R * C == size."""
    rows = int(np.sqrt(size))
    while size % rows:
        rows -= 1
    return rows, size // rows


def _calls_per_repeat(call: Callable[[], object], budget_s: float) -> int:
    """Return how many calls take about ``budget_s``."""
    start = time.thread_time()
    call()
    once = max(time.thread_time() - start, 1e-7)
    return max(1, int(budget_s / once))


def _paired(
    call: Callable[[], object], floor: Callable[[], object], repeats: int, budget_s: float = 0.02
) -> tuple[float, float]:
    """Best time per call of ``call`` and of ``floor``, measured alternately."""
    call()  # warm caches (cached coefficients, allocator)
    n_call = _calls_per_repeat(call, budget_s)
    n_floor = _calls_per_repeat(floor, budget_s)
    best, best_floor = np.inf, np.inf
    for _ in range(repeats):
        best = min(best, timeit.timeit(call, timer=CPU_TIMER, number=n_call) / n_call)
        best_floor = min(
            best_floor, timeit.timeit(floor, timer=CPU_TIMER, number=n_floor) / n_floor
        )
    return best, best_floor


def _moving_setpoints(rng: np.random.Generator, shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """Set point sequences [m] (frames x grid) that the observer workloads cycle through."""
    frames = np.arange(200)[:, None, None] / 2000.0  # one period of 10 Hz at 2 kHz
    phase = rng.uniform(0.0, 2.0 * np.pi, shape)
    return {
        "10hz": 75e-9 + 75e-9 * np.sin(2.0 * np.pi * 10.0 * frames + phase),
        "jumps": rng.uniform(0.0, 150e-9, (16, *shape)),
    }


def _cycling(ff: Feedforward, trajectory: np.ndarray) -> Callable[[], object]:
    """Return a call that commands the next frame of ``trajectory``, round and round."""
    frames = itertools.cycle(list(trajectory))
    ff.command(trajectory[-1], 0.0)  # start from the frame before the first
    return lambda: ff.command(next(frames), 0.0)


def _cycling_in_time(ff: Feedforward, trajectory: np.ndarray) -> Callable[[], object]:
    """Return a call that commands the next frame of ``trajectory``, one FRAME_PERIOD later."""
    frames = itertools.cycle(list(trajectory))
    clock = itertools.count(1)
    ff.command(trajectory[-1], 0.0)

    def call() -> object:
        return ff.command(next(frames), next(clock) * FRAME_PERIOD)

    return call


def _update_counts(config: FeedforwardConfig, T: np.ndarray, trajectory: np.ndarray) -> list[int]:
    """Return the observer updates each frame of ``trajectory`` takes, in order.

    The observer's loop as :func:`_cycling` drives it (from rest to the last frame, then once
    round), through :func:`es_feedforward.kernels.observer_command` directly.
    """
    gains = config.observer
    laws = CompiledLaws(config.params, config.shape).at(T)
    integral = np.zeros(config.shape)
    counts = []
    for frame in (trajectory[-1], *trajectory):
        out = observer_command(integral, laws, frame, v_limit=config.v_limit, kp=gains.kp,
                               ki=gains.ki, iterations=gains.iterations,
                               tolerance=gains.tolerance)  # fmt: skip
        integral = out.integral
        counts.append(out.updates)
    return counts[1:]


def _observer_arithmetic(size: int, counts: list[int], iterations: int) -> Callable[[], object]:
    """Return the numpy SIMD passes the observer's arithmetic needs, set point after set point.

    For a set point of k updates (``counts``, round and round, as :func:`_cycling` goes):
    one ``np.sqrt`` (the targets), a ``np.divide`` per step (its error over the local gain),
    a ``np.tanh`` per update (the model at the new command), and a ``np.divide`` for the
    model error; k + 1 steps (the last finds nothing to move) unless k is ``iterations``.
    Nothing else (no clipping, no comparisons, no buffers, no Python around it): no
    implementation of these updates on numpy's SIMD functions does less.
    """
    rng = np.random.default_rng(size)
    a, b = rng.uniform(0.1, 0.9, size), rng.uniform(0.1, 0.9, size)
    out = np.empty(size)
    work = itertools.cycle([(k + (k < iterations), k) for k in counts])

    def arithmetic() -> None:
        steps, updates = next(work)
        np.sqrt(a, out=out)
        for _ in range(steps):
            np.divide(a, b, out=out)
        for _ in range(updates):
            np.tanh(a, out=out)
        np.divide(a, b, out=out)

    return arithmetic


def bench_kernels(
    sizes: Sequence[int] = DEFAULT_SIZES, repeats: int = 5, numpy_too: bool = False
) -> list[KernelTiming]:
    """Time every kernel for every grid size; return one :class:`KernelTiming` per pair.

    ``numpy_too`` adds the observer on the pure-numpy path when the fused one is the default.
    """
    rows_out: list[KernelTiming] = []
    for size in sizes:
        shape = grid_shape(size)
        rng = np.random.default_rng(size)
        params = ActuatorParams(
            m1=rng.uniform(-45e-18, -38e-18, shape),
            m2=rng.uniform(1300e-18, 1700e-18, shape),
            k1=rng.uniform(-19e-9, -16e-9, shape),
            k2=rng.uniform(1100e-9, 1250e-9, shape),
        )
        z = rng.uniform(0.0, 150e-9, shape)
        T = rng.uniform(40.0, 52.0, shape)
        ratio = rng.uniform(0.0, 0.9, shape)

        def floor(ratio: np.ndarray = ratio) -> object:
            return np.sqrt(ratio)

        compiled = CompiledLaws(params, shape)
        kernels: dict[str, Callable[[], object]] = {
            "laws+inverse_hyperbolic": partial(compiled.hyperbolic_inverse, z, T, DEFAULT_V_LIMIT)
        }
        for mode in Mode:
            ff = Feedforward(FeedforwardConfig(shape=shape, params=params, mode=mode))
            ff.update_temperature(T, 0.0)
            kernels[mode.value] = partial(ff.command, z, 0.0)
            if mode is Mode.OBSERVER:
                for workload, trajectory in _moving_setpoints(rng, shape).items():
                    moving = Feedforward(ff.config)
                    moving.update_temperature(T, 0.0)
                    kernels[f"{mode.value}_{workload}"] = _cycling(moving, trajectory)
                    counts = _update_counts(ff.config, T, trajectory)
                    kernels[f"{mode.value}_{workload}{FLOOR_SUFFIX}"] = _observer_arithmetic(
                        size, counts, ff.config.observer.iterations
                    )
            if numpy_too and mode is Mode.OBSERVER and ff.backend is not Backend.NUMPY:
                plain = Feedforward(ff.config, backend=Backend.NUMPY)
                plain.update_temperature(T, 0.0)
                kernels[f"{mode.value}_numpy"] = partial(plain.command, z, 0.0)
        sine = _moving_setpoints(rng, shape)["10hz"]
        for kind, terms in (("none", []), *((k, [t]) for k, t in DISCOVERED.items())):
            compensation = CompensationParams().replaced(values_from_terms(terms))
            ff = Feedforward(FeedforwardConfig(shape=shape, params=params,
                                               compensation=compensation))
            ff.update_temperature(T, 0.0)
            kernels[f"discovered_{kind}_10hz"] = _cycling_in_time(ff, sine)
        ff = Feedforward(FeedforwardConfig(shape=shape, params=params))
        kernels["update_temperature"] = partial(ff.update_temperature, T, 0.0)
        for name, call in kernels.items():
            seconds, sqrt_seconds = _paired(call, floor, repeats)
            rows_out.append(KernelTiming(name, size, seconds, sqrt_seconds))
    return rows_out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the benchmark table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default=",".join(map(str, DEFAULT_SIZES)))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--numpy-too", action="store_true",
                        help="also time the observer on the pure-numpy path")
    args = parser.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]
    print(f"{'kernel':26s} {'N':>6s} {'us/call':>10s} {'sqrt us':>9s} {'x sqrt':>8s}")
    for row in bench_kernels(sizes, args.repeats, args.numpy_too):
        print(
            f"{row.kernel:26s} {row.size:6d} {row.seconds_per_call * 1e6:10.2f} "
            f"{row.sqrt_seconds_per_call * 1e6:9.3f} {row.ratio_to_sqrt:8.1f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
