"""Benchmark of the calibration tool: wall time of ``calibrate`` on measured-data bags.

Cases: 1 x 1 and 32 x 32 actuators, 5 minutes at 500 Hz (150 000 commands and displacements,
temperatures at 10 Hz). The bags are generated once per call into a temporary directory with
the model library (hyperbolic law, 2 % actuator spread, one thermal-expansion effect so the
effect search also refits the whole grid, 0.5 nm interferometer noise) and written in blocks,
so generating a 32 x 32 bag needs no full-size array. The drive switches its offset,
amplitude and frequency every second, at the same instants for every actuator, or with
``--independent`` at each actuator's own instants (a test stand's characterisation drive:
every actuator then has its own command edges, issue 33). Run:

    .venv/bin/python bench/bench_calibrate.py [--grid 32] [--duration 300] [--rate 500]
        [--independent]

The timed part is what ``es_calibration-calibrate BAG -o OUT`` does (read the bag, calibrate,
write report, JSON and YAML), in this process; the bag is generated in a child process, so
this process's peak resident memory is the calibration's (with the interpreter's). Nothing
is asserted.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import resource
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from es_calibration.calibrate import run
from es_calibration.verdict import WRITTEN
from es_msgs_py.bag import FLOAT64_MULTI_ARRAY, BagWriter, encode_float64_multi_array
from es_physics.laws import hyperbolic_forward
from es_physics.params import ActuatorParams

BLOCK_STEPS = 5000
EXPANSION_M_PER_DEGC = 0.4e-9


@dataclass(frozen=True)
class CalibrationTiming:
    """Wall time of one calibration run."""

    rows: int
    cols: int
    duration_s: float
    rate_hz: float
    generate_s: float
    calibrate_s: float
    #: this process's peak resident set size after the calibration [bytes] (the
    #: calibration's peak when it was the first run of the process)
    peak_rss_bytes: int
    #: calibration.json's share of the (sample, actuator) pairs kept: the whole grid's
    #: where the grid is larger than the screening block, else the block's.
    kept_fraction: float


def write_measured_bag(
    path: Path, rows: int, cols: int, duration: float, rate: float, *, seed: int = 0,
    independent: bool = False,
) -> None:
    """Write a synthetic measured-data bag (see the module docstring) to ``path``."""
    rng = np.random.default_rng(seed)
    shape = (rows, cols)
    params = ActuatorParams().as_arrays(shape)
    params = ActuatorParams(
        m1=params.m1,
        m2=params.m2 * (1 + 0.02 * rng.standard_normal(shape)),
        m3=0.0,
        k1=params.k1,
        k2=params.k2 * (1 + 0.01 * rng.standard_normal(shape)),
        k3=0.0,
    )
    phase = rng.uniform(0, 2 * np.pi, shape)
    spatial = rng.uniform(-0.5, 0.5, shape)
    # when each actuator's drive switches, within each second [s]
    switch = rng.uniform(0.0, 1.0, shape) if independent else np.zeros(shape)
    steps = int(duration * rate)
    sensor_every = int(rate // 10)

    def temperature(t: np.ndarray) -> np.ndarray:
        ramp = 40.0 + 12.0 * np.sin(np.pi * t / duration)
        return ramp[:, None, None] + spatial[None] * (ramp[:, None, None] - 40.0) / 12.0

    with BagWriter(path) as bag:
        for start in range(0, steps, BLOCK_STEPS):
            k = np.arange(start, min(start + BLOCK_STEPS, steps))
            t = k / rate
            level = ((t[:, None, None] + switch[None]) // 1.0).astype(int)
            offset = np.where(level % 2 == 0, 0.0, 100.0)
            amplitude = np.array([50.0, 150.0, 250.0])[level % 3]
            freq = np.where((level // 3) % 2 == 0, 1.0, 4.0)
            V = offset + amplitude * np.sin(2 * np.pi * freq * t[:, None, None] + phase[None])
            T = temperature(t + 1.0 / rate)
            z = hyperbolic_forward(V, T, params) + EXPANSION_M_PER_DEGC * (T - 40.0)
            z += 0.5e-9 * rng.standard_normal(z.shape)
            for i, tk in enumerate(t):
                ns = round(tk * 1e9)
                bag.write(
                    "/dm/command", ns, encode_float64_multi_array(V[i], "grid"), FLOAT64_MULTI_ARRAY
                )
                bag.write(
                    "/dm/displacement",
                    round((tk + 1.0 / rate) * 1e9),
                    encode_float64_multi_array(z[i], "grid"),
                    FLOAT64_MULTI_ARRAY,
                )
                if k[i] % sensor_every == 0:
                    bag.write(
                        "/dm/temperature/raw",
                        ns,
                        encode_float64_multi_array(temperature(t[i : i + 1])[0].ravel(), "sensor"),
                        FLOAT64_MULTI_ARRAY,
                    )


def bench_calibrate(
    rows: int = 32, cols: int = 32, duration: float = 300.0, rate: float = 500.0,
    independent: bool = False,
) -> CalibrationTiming:
    """Generate one bag, then time the calibration tool on it."""
    with tempfile.TemporaryDirectory(prefix="bench_calibrate_") as tmp:
        bag = Path(tmp) / "bag"
        start = time.perf_counter()
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
            pool.submit(write_measured_bag, bag, rows, cols, duration, rate,
                        independent=independent).result()
        generated = time.perf_counter() - start
        start = time.perf_counter()
        status = run([str(bag), "-o", str(Path(tmp) / "out"), "-q"])
        elapsed = time.perf_counter() - start
        if status not in WRITTEN:
            raise RuntimeError(f"calibrate exited with {status}")
        health = json.loads((Path(tmp) / "out" / "calibration.json").read_text())["health"]
    kept = health["grid_kept_fraction"]
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: kB
    return CalibrationTiming(rows, cols, duration, rate, generated, elapsed, peak,
                             health["kept_fraction"] if kept is None else kept)


def main() -> None:
    """Run the benchmark cases and print their timings."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=int, nargs="*", default=[1, 32])
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--rate", type=float, default=500.0)
    parser.add_argument("--independent", action="store_true",
                        help="each actuator's drive switches at its own instants")
    args = parser.parse_args()
    for n in args.grid:
        timing = bench_calibrate(n, n, args.duration, args.rate, args.independent)
        print(
            f"calibrate {n} x {n}, {args.duration:g} s at {args.rate:g} Hz: "
            f"{timing.calibrate_s:.1f} s (bag generation {timing.generate_s:.1f} s), "
            f"{100 * timing.kept_fraction:.1f} % of the samples kept, peak resident memory "
            f"{timing.peak_rss_bytes / 1e9:.2f} GB"
        )


if __name__ == "__main__":
    main()
