"""``calibrate_resonance`` on characterisation bags: the parameters file, and bad input."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import yaml
from support.ros import executable

from es_msgs_py.bag import write_array_bag

ROWS, COLS, SENSORS = 4, 5, 4
F0, A_T, A_V, T0 = 1.0e6, 3227.0, -80.0, 40.0


def characterisation_bag(path: Path, *, with_resonance: bool = True, ramp: float = 12.0) -> dict:
    """Write a test-stand bag with a few lines of numpy; return the true laws."""
    rng = np.random.default_rng(3)
    k = 400
    times = 0.1 * np.arange(k)
    f0 = F0 + 4e3 * rng.standard_normal((ROWS, COLS))
    a_t = A_T * (1 + 0.03 * rng.standard_normal((ROWS, COLS)))
    a_v = A_V * (1 + 0.1 * rng.standard_normal((ROWS, COLS)))
    stage = T0 + ramp * np.sin(np.linspace(0.0, np.pi, k))
    volts = rng.uniform(-300.0, 300.0, (k, ROWS, COLS))
    # the sweep at t_k runs under the command stamped before it (volts[k - 1])
    in_force = np.concatenate([np.zeros((1, ROWS, COLS)), volts[:-1]])
    freq = f0 + a_t * (stage[:, None, None] - T0) + a_v * np.abs(in_force)
    freq += 15.0 * rng.standard_normal(freq.shape)
    freq[(np.arange(k)[:, None, None] + np.arange(ROWS * COLS).reshape(ROWS, COLS)) % 2 == 1] = (
        np.nan
    )
    raw = stage[:, None] + 0.02 * rng.standard_normal((k, SENSORS))
    series = {
        "/dm/command": (times, volts),
        "/dm/temperature/raw": (times, raw),
    }
    if with_resonance:
        series["/dm/resonance"] = (times, freq)
    write_array_bag(path, series)
    return {"f0": f0, "a_t": a_t, "a_v": a_v}


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(executable("es_thermal", "calibrate_resonance")), *args],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip


def test_writes_the_thermal_parameters_file(tmp_path: Path) -> None:
    truth = characterisation_bag(tmp_path / "stand")
    out = tmp_path / "thermal_params.yaml"
    done = run(str(tmp_path / "stand"), "-o", str(out), "--reference-temperature", "40")
    assert done.returncode == 0, done.stderr
    assert "calibrated 20 of 20 channels" in done.stdout
    params = yaml.safe_load(out.read_text())["thermal"]["ros__parameters"]
    assert (params["rows"], params["cols"]) == (ROWS, COLS)
    f0 = np.reshape(params["resonance.f0_hz"], (ROWS, COLS))
    f0_sd = np.reshape(params["resonance.f0_sd_hz"], (ROWS, COLS))
    a_t = np.reshape(params["resonance.a_t_hz_per_degc"], (ROWS, COLS))
    a_v = np.reshape(params["resonance.a_v_hz_per_v"], (ROWS, COLS))
    assert np.all(np.abs(f0 - truth["f0"]) < 5 * f0_sd)
    a_t_sd = np.reshape(params["resonance.a_t_sd"], a_t.shape)
    a_v_sd = np.reshape(params["resonance.a_v_sd"], a_v.shape)
    assert np.all(np.abs(a_t - truth["a_t"]) < 5 * a_t_sd)
    assert np.all(np.abs(a_v - truth["a_v"]) < 5 * a_v_sd)
    assert params["resonance.reference_temperature"] == 40.0
    # residual scatter: the 15 Hz reading noise plus the stage reference's noise
    # (0.02 degC / sqrt(4) sensors = 32 Hz)
    assert 30.0 < params["resonance.noise_hz"] < 40.0
    assert "resonance.disabled_channels" not in params


def test_bad_input_ends_with_one_line_and_status_2(tmp_path: Path) -> None:
    characterisation_bag(tmp_path / "no_resonance", with_resonance=False)
    characterisation_bag(tmp_path / "no_ramp", ramp=0.0)
    (tmp_path / "corrupt").mkdir()
    (tmp_path / "corrupt" / "metadata.yaml").write_text("{not: a bag")
    for bag, reason in (
        (tmp_path / "missing", "missing"),
        (tmp_path / "corrupt", ""),
        (tmp_path / "no_resonance", "/dm/resonance"),
        (tmp_path / "no_ramp", "ramp"),
    ):
        done = run(str(bag), "-o", str(tmp_path / "out.yaml"))
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2, (bag, done.stderr)
        assert len(lines) == 1 and lines[0].startswith("calibrate_resonance: "), done.stderr
        assert reason.lower() in lines[0].lower()
        assert not (tmp_path / "out.yaml").exists()
