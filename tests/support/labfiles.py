"""Small lab recordings in every format the importer reads, written the way the tools do.

A :class:`Recording` is the truth in contract units (V, m, degC) on a 3 x 4 grid with two
temperature sensors at their own rate; each ``write_*`` stores it in a file the way a lab
would (other units, MATLAB column-major vectors, timeseries structs, numbered CSV columns)
and returns the map (a dict) that imports it back.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import scipy.io
import yaml

MAT73_HEADER = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Sun Nov 22 12:00:00 2026 HDF5"


@dataclass
class Recording:
    """Truth: command (N, 3, 4) V, displacement (N, 3, 4) m, temperature (M, 2) degC."""

    t: np.ndarray
    command: np.ndarray
    displacement: np.ndarray
    temperature_t: np.ndarray
    temperature: np.ndarray


def recording(n: int = 300, rate: float = 1000.0, seed: int = 3) -> Recording:
    rng = np.random.default_rng(seed)
    t = 0.5 + np.arange(n) / rate
    command = rng.uniform(0, 200, (n, 3, 4))
    displacement = rng.normal(0, 50e-9, (n, 3, 4))
    m = n // 10
    temperature = 40 + rng.normal(0, 0.5, (m, 2))
    return Recording(t, command, displacement, np.arange(m) / (rate / 10), temperature)


def flat_f(grids: np.ndarray) -> np.ndarray:
    """(N, R, C) -> (N, R*C) in column-major order (MATLAB's grid(:)')."""
    return grids.transpose(0, 2, 1).reshape(len(grids), -1)


def flat_c(grids: np.ndarray) -> np.ndarray:
    return grids.reshape(len(grids), -1)


def write_map(path: Path, document: dict[str, Any]) -> Path:
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    return path


def _mat_map() -> dict[str, Any]:
    return {
        "time": {"variable": "t", "unit": "s"},
        "topics": {
            "/dm/command": {"variable": "u", "unit": "mV", "grid": [3, 4], "order": "F"},
            "/dm/displacement": {"variable": "y", "unit": "nm", "grid": [3, 4]},
            "/dm/temperature/raw": {"variable": "T", "unit": "K", "sensors": 2,
                                    "time": {"start": 0.0, "rate": 100.0}},
        },
    }


def write_mat(path: Path, rec: Recording) -> dict[str, Any]:
    """MATLAB v5: t as N x 1, u as N x 12 (column-major grid, mV), y a Simulink-like
    timeseries struct (Time N x 1, Data 3 x 4 x N, nm), T an M x 2 matrix in K."""
    scipy.io.savemat(path, {
        "t": rec.t[:, None],
        "u": flat_f(rec.command) * 1e3,
        "y": {"Time": rec.t[:, None], "Data": rec.displacement.transpose(1, 2, 0) * 1e9},
        "T": rec.temperature + 273.15,
    })
    return _mat_map()


def _mat73_dataset(group: h5py.Group, name: str, matlab_array: np.ndarray) -> None:
    """Store an array as MATLAB does: its dimensions reversed (column-major on disk)."""
    data = np.asarray(matlab_array, dtype=np.float64)
    dataset = group.create_dataset(name, data=data.transpose(*reversed(range(data.ndim))))
    dataset.attrs["MATLAB_class"] = np.bytes_("double")


def write_mat73(path: Path, rec: Recording) -> dict[str, Any]:
    """The same variables as :func:`write_mat`, in a MATLAB v7.3 (HDF5) file."""
    with h5py.File(path, "w", userblock_size=512) as f:
        _mat73_dataset(f, "t", rec.t[:, None])
        _mat73_dataset(f, "u", flat_f(rec.command) * 1e3)
        y = f.create_group("y")
        y.attrs["MATLAB_class"] = np.bytes_("struct")
        _mat73_dataset(y, "Time", rec.t[:, None])
        _mat73_dataset(y, "Data", rec.displacement.transpose(1, 2, 0) * 1e9)
        _mat73_dataset(f, "T", rec.temperature + 273.15)
        f.create_dataset("name", data=np.frombuffer(b"r\x00i\x00g\x00", np.uint16)[:, None])
        f["name"].attrs["MATLAB_class"] = np.bytes_("char")
    with path.open("r+b") as handle:
        handle.write(MAT73_HEADER.ljust(128, b" "))
    return _mat_map()


def write_h5(path: Path, rec: Recording) -> dict[str, Any]:
    """HDF5 as C code writes it: time in ms, grids (N, 3, 4) and (N, 12) row-major."""
    with h5py.File(path, "w") as f:
        f["time_ms"] = rec.t * 1e3
        f["data/cmd"] = rec.command * 1e-3
        f["data/disp"] = flat_c(rec.displacement) * 1e6
        f["data/temp"] = rec.temperature
        f["data/temp_t"] = rec.temperature_t
    return {
        "time": {"variable": "time_ms", "unit": "ms"},
        "topics": {
            "/dm/command": {"variable": "data/cmd", "unit": "kV", "grid": [3, 4]},
            "/dm/displacement": {"variable": "data/disp", "unit": "um", "grid": [3, 4]},
            "/dm/temperature/raw": {"variable": "data/temp", "unit": "degC", "sensors": 2,
                                    "time": {"variable": "data/temp_t"}},
        },
    }


def write_csv(path: Path, rec: Recording, delimiter: str = ",") -> dict[str, Any]:
    """One row per sample: t, cmd_0..cmd_11 (row-major), disp_0..disp_11 in mm; the two
    temperature columns only every 10th row (empty cells elsewhere)."""
    n = len(rec.t)
    header = ["t", *[f"cmd_{i}" for i in range(12)], *[f"disp_{i}" for i in range(12)],
              "temp_a", "temp_b"]
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle, delimiter=delimiter)
        writer.writerow(header)
        cmd, disp = flat_c(rec.command).tolist(), (flat_c(rec.displacement) * 1e3).tolist()
        temperature, t = rec.temperature.tolist(), rec.t.tolist()
        for i in range(n):
            temps = [repr(v) for v in temperature[i // 10]] if i % 10 == 0 else ["", ""]
            writer.writerow([repr(t[i]), *map(repr, cmd[i]), *map(repr, disp[i]), *temps])
    return {
        "time": {"variable": "t"},
        "topics": {
            "/dm/command": {"prefix": "cmd_", "unit": "V", "grid": [3, 4]},
            "/dm/displacement": {"prefix": "disp_", "unit": "mm", "grid": [3, 4]},
        },
    }


def write_npz(path: Path, rec: Recording) -> dict[str, Any]:
    """NumPy archive: t, command (N, 3, 4), displacement (N, 12), temperature (M, 2)."""
    np.savez(path, t=rec.t, command=rec.command, displacement=flat_c(rec.displacement),
             temperature=rec.temperature, temperature_t=rec.temperature_t)
    return {
        "time": {"variable": "t"},
        "topics": {
            "/dm/command": {"variable": "command", "unit": "V", "grid": [3, 4]},
            "/dm/displacement": {"variable": "displacement", "unit": "m", "grid": [3, 4]},
            "/dm/temperature/raw": {"variable": "temperature", "unit": "degC", "sensors": 2,
                                    "time": {"variable": "temperature_t"}},
        },
    }
