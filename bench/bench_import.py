"""Benchmark of the lab-recording import: wall time and peak memory of ``import``.

Cases (issue 19): 5 minutes at 5 kHz of a 1 x 1 recording (1.5 M samples per topic) and
1 minute at 500 Hz of a 32 x 32 one (30 000 samples of 1024 values per topic), each with
/dm/command (V) and /dm/displacement (m) on one time variable, in HDF5, MATLAB v7.3, CSV,
MATLAB v5 and .npz. Each import runs in a fresh child process that reports its wall time
and its peak resident memory (VmHWM) together with its resident memory just before the
import (the interpreter with numpy, scipy, h5py and rosbags loaded), so the import's own
peak is the difference. The same 1 x 1 case at a fifth of the length shows whether memory
grows with the recording's length. Run:

    .venv/bin/python bench/bench_import.py [--quick] [--formats hdf5 csv]

Files are generated in blocks into a temporary directory (the .mat v5 and .npz writers need
whole arrays). Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import scipy.io
import yaml

FORMATS = ("hdf5", "mat73", "csv", "mat5", "npz")
SUFFIX = {"hdf5": ".h5", "mat73": ".mat", "csv": ".csv", "mat5": ".mat", "npz": ".npz"}
#: (rows, cols, seconds, rate) of the issue's cases; --quick divides the seconds by 10.
CASES = ((1, 1, 300.0, 5000.0), (32, 32, 60.0, 500.0))
BLOCK = 20_000
MAT73_HEADER = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: bench HDF5 schema 1.00 ."


@dataclass(frozen=True)
class ImportTiming:
    """One import: wall time [s], peak and baseline resident memory [MiB], sizes."""

    fmt: str
    rows: int
    cols: int
    samples: int
    seconds: float
    peak_mib: float
    baseline_mib: float
    file_mib: float

    @property
    def import_mib(self) -> float:
        """Peak memory above the loaded interpreter's [MiB]."""
        return self.peak_mib - self.baseline_mib


def _block(start: int, stop: int, size: int, rate: float) -> tuple[np.ndarray, ...]:
    t = np.arange(start, stop) / rate
    phase = np.linspace(0, 1, size)
    volts = 100 + 80 * np.sin(2 * np.pi * t[:, None] + phase[None])
    return t, volts, volts * 1e-9


def write_recording(fmt: str, path: Path, size: int, samples: int, rate: float) -> None:
    """Write ``samples`` of a ``size``-actuator recording in format ``fmt`` to ``path``."""
    if fmt in ("hdf5", "mat73"):
        matlab = fmt == "mat73"
        with h5py.File(path, "w", userblock_size=512 if matlab else 0) as f:
            shape = (lambda n: (size, n)) if matlab else (lambda n: (n, size))
            t = f.create_dataset("t", (1, samples) if matlab else (samples,), "f8")
            u = f.create_dataset("u", shape(samples), "f8", chunks=True)
            z = f.create_dataset("z", shape(samples), "f8", chunks=True)
            for start in range(0, samples, BLOCK):
                stop = min(start + BLOCK, samples)
                tb, ub, zb = _block(start, stop, size, rate)
                if matlab:
                    t[0, start:stop], u[:, start:stop], z[:, start:stop] = tb, ub.T, zb.T
                else:
                    t[start:stop], u[start:stop], z[start:stop] = tb, ub, zb
        if matlab:
            with path.open("r+b") as handle:
                handle.write(MAT73_HEADER.ljust(128, b" "))
        return
    if fmt == "csv":
        header = ",".join(["t", *[f"u_{i}" for i in range(size)], *[f"z_{i}" for i in range(size)]])
        with path.open("w") as handle:
            handle.write(header + "\n")
            for start in range(0, samples, BLOCK):
                tb, ub, zb = _block(start, min(start + BLOCK, samples), size, rate)
                np.savetxt(handle, np.hstack([tb[:, None], ub, zb]), fmt="%.10g", delimiter=",")
        return
    t, u, z = _block(0, samples, size, rate)
    if fmt == "mat5":
        scipy.io.savemat(path, {"t": t[:, None], "u": u, "z": z})
    else:
        np.savez(path, t=t, u=u, z=z)


def _map(fmt: str, rows: int, cols: int) -> dict[str, object]:
    def entry(name: str, unit: str) -> dict[str, object]:
        where = {"prefix": f"{name}_"} if fmt == "csv" else {"variable": name}
        return {**where, "unit": unit, "grid": [rows, cols]}

    return {"time": {"variable": "t"},
            "topics": {"/dm/command": entry("u", "V"), "/dm/displacement": entry("z", "m")}}


def _child(source: str, map_path: str, bag: str) -> None:
    """Child process: import once, print {seconds, peak_mib, baseline_mib} as JSON."""
    import h5py as _h5py  # noqa: F401  (loaded before the baseline, like the readers need)
    import scipy.io as _scipy_io  # noqa: F401

    from es_recordings.labimport import import_recording, load_map

    def status(key: str) -> float:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key):
                return int(line.split()[1]) / 1024
        return float("nan")

    baseline = status("VmRSS")
    start = time.perf_counter()
    import_recording(source, bag, load_map(map_path))
    seconds = time.perf_counter() - start
    print(json.dumps({"seconds": seconds, "peak_mib": status("VmHWM"), "baseline_mib": baseline}))


def bench_import(fmt: str, rows: int, cols: int, duration: float, rate: float, *,
                 workdir: Path) -> ImportTiming:
    """Generate one recording in ``workdir``, import it in a child process, time it."""
    samples = int(duration * rate)
    source = workdir / f"rec_{fmt}_{rows}x{cols}_{samples}{SUFFIX[fmt]}"
    write_recording(fmt, source, rows * cols, samples, rate)
    map_path = workdir / f"map_{fmt}_{rows}x{cols}.yaml"
    map_path.write_text(yaml.safe_dump(_map(fmt, rows, cols)))
    bag = workdir / f"bag_{source.stem}"
    try:
        proc = subprocess.run([sys.executable, __file__, "--child", str(source), str(map_path),
                               str(bag)], capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise RuntimeError(f"import of {source.name} failed: {proc.stderr.strip()[-500:]}")
        report = json.loads(proc.stdout.strip().splitlines()[-1])
        return ImportTiming(fmt, rows, cols, samples, report["seconds"], report["peak_mib"],
                            report["baseline_mib"], source.stat().st_size / 2**20)
    finally:
        source.unlink(missing_ok=True)
        if bag.exists():
            for file in bag.iterdir():
                file.unlink()
            bag.rmdir()


def run_cases(quick: bool, formats: tuple[str, ...] = FORMATS,
              progress: Callable[[ImportTiming], None] | None = None) -> list[ImportTiming]:
    """Run every case in every format (and the shorter 1 x 1 memory check in HDF5 and CSV)."""
    scale = 0.1 if quick else 1.0
    timings = []
    with tempfile.TemporaryDirectory(prefix="bench_import_") as tmp:
        cases = [(r, c, d * scale, rate, fmts) for r, c, d, rate in CASES
                 for fmts in [formats]]
        cases.append((1, 1, CASES[0][2] * scale / 5, CASES[0][3],
                      tuple(f for f in formats if f in ("hdf5", "csv"))))
        for rows, cols, duration, rate, fmts in cases:
            for fmt in fmts:
                timing = bench_import(fmt, rows, cols, duration, rate, workdir=Path(tmp))
                timings.append(timing)
                if progress is not None:
                    progress(timing)
    return timings


def describe(t: ImportTiming) -> str:
    """One line per import."""
    return (f"{t.fmt:6s} {t.rows} x {t.cols}, {t.samples} samples ({t.file_mib:.0f} MiB file): "
            f"{t.seconds:.2f} s, peak {t.peak_mib:.0f} MiB ({t.import_mib:.0f} MiB above the "
            f"loaded interpreter's {t.baseline_mib:.0f})")


def main() -> None:
    """Command line: run the cases and print one line each."""
    if len(sys.argv) == 5 and sys.argv[1] == "--child":
        _child(*sys.argv[2:])
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a tenth of the issue's lengths")
    parser.add_argument("--formats", nargs="+", choices=FORMATS, default=list(FORMATS))
    args = parser.parse_args()
    run_cases(args.quick, tuple(args.formats), lambda t: print(describe(t), flush=True))


if __name__ == "__main__":
    main()
