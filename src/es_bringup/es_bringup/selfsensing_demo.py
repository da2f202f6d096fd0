"""The main job's self-sensing section: files, calibration, scoring and text (no rclpy).

The demo (:mod:`es_bringup.demo`) runs, over ROS 2 through the bring-up:

1. a test stand of the ``dm_exposure`` mirror with the resonance sweeps on
   (:func:`stand_scenario`), recording /dm/resonance besides the usual topics;
2. ``calibrate_resonance`` on its sample-clock copy (:func:`sample_clock_copy`,
   :func:`calibrate`), which writes the thermal node's ``resonance.*`` parameters;
3. ``dm_exposure`` in closed loop three times (:func:`case_scenarios`): (a) 4 NTCs and the
   thermal model, (b) the same plus self-sensing (the thermal node gets the calibrated
   ``resonance.*``), (c) an NTC on every actuator; the plant is the same mirror with the
   sweeps on in all three.

Each run's /dm/temperature is scored against the simulator's true actuator temperatures
(:func:`temperature_errors`: the plant core run offline, with the run's control rate; the
thermal network does not depend on the commands unless ``self_heating`` is on), paired by
sample index (the thermal node publishes one estimate per raw sample, in lockstep).
"""

from __future__ import annotations

import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import matplotlib

matplotlib.use("Agg")  # files only; never a window
import matplotlib.pyplot as plt
import numpy as np
import yaml

from es_bringup.bringup import ParamValue, executable
from es_bringup.selfsensing_study import CASE_TITLES, CASES, SKIP_FRACTION
from es_common.arrays import FloatArray
from es_msgs_py.bag import read_bag, write_array_bag
from es_sim_plant.plant import Plant, sensor_every, simulate
from es_sim_plant.scenario import load_scenario
from es_thermal.interpolation import block_centre_positions

#: The mirror and exposure of the section (12 x 12, dipole: a non-uniform heat load).
SCENARIO: Final = "dm_exposure"
#: NTCs of cases (a) and (b): one per pitch x pitch block (4 on 12 x 12).
NTC_PITCH: Final = 6
# The contract's topic names (es_msgs_py.topics imports rclpy; this module does not need it).
_COMMAND, _RESONANCE, _RAW, _TEMPERATURE = (
    "/dm/command", "/dm/resonance", "/dm/temperature/raw", "/dm/temperature",
)  # fmt: skip


class SelfSensingError(RuntimeError):
    """A step of the self-sensing section failed; the message is one readable line."""


@dataclass(frozen=True)
class CaseFigures:
    """Scores of one closed-loop case: per-actuator RMS map (R, C) [degC] and more."""

    name: str
    rms_map: FloatArray
    rms: float
    worst: float
    max_error: float
    variation_m: float


def _write(data: dict[str, Any], out: Path) -> Path:
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    load_scenario(str(out))  # fail here, readably, if the combination is invalid
    return out


def stand_scenario(stand: Path, out_dir: Path) -> Path:
    """Write the test stand ``stand`` (a scenario file) with the resonance sweeps on."""
    data = yaml.safe_load(stand.read_text())
    data["name"] = f"{data['name']}_resonance"
    data["description"] = f"{data.get('description', '')}, resonance sweeps on"
    data["resonance"] = {**(data.get("resonance") or {}), "enabled": True}
    return _write(data, out_dir / f"{data['name']}.yaml")


def case_scenarios(source: Path, out_dir: Path) -> dict[str, Path]:
    """Write the scenario of every case of :data:`CASES` from the scenario file ``source``.

    Same mirror and exposure, sweeps on; 4 NTCs (one per :data:`NTC_PITCH` block) for
    ``ntc`` and ``ntc_selfsensing`` (the same file), one per actuator for
    ``sensor_per_actuator``.
    """
    data = yaml.safe_load(source.read_text())
    data["resonance"] = {**(data.get("resonance") or {}), "enabled": True}
    rows, cols = int(data["grid"]["rows"]), int(data["grid"]["cols"])
    base = str(data["name"])
    ntc = dict(data)
    ntc["name"] = f"{base}_ntc{NTC_PITCH}"
    ntc["sensors"] = {
        **(data.get("sensors") or {}),
        "positions": [
            [float(r), float(c)] for r, c in block_centre_positions(rows, cols, NTC_PITCH)
        ],
    }
    every = dict(data)
    every["name"] = f"{base}_ntc_every"
    every["sensors"] = {**(data.get("sensors") or {}), "positions": None}
    few = _write(ntc, out_dir / f"{ntc['name']}.yaml")
    return {
        "ntc": few,
        "ntc_selfsensing": few,
        "sensor_per_actuator": _write(every, out_dir / f"{every['name']}.yaml"),
    }


def sample_clock_copy(bag: Path, out: Path, scenario: str) -> Path:
    """Write /dm/command, /dm/resonance and /dm/temperature/raw of a test stand by index.

    As the demo's calibration copy: step k's command at k / control_rate, sensor sample j
    (and its sweep) at step j * sensor_every; the messages are unchanged.
    """
    sc = load_scenario(scenario)
    every = sensor_every(sc.control_rate, sc.sensor_rate)
    data = read_bag(bag, [_COMMAND, _RESONANCE, _RAW])
    series = {}
    for topic, step in ((_COMMAND, 1), (_RESONANCE, every), (_RAW, every)):
        values = data[topic].values
        if values is None or len(values) == 0:
            raise SelfSensingError(f"{bag}: no {topic} recorded")
        series[topic] = (np.arange(len(values)) * step / sc.control_rate, values)
    write_array_bag(out, series)
    return out


def calibrate(bag: Path, out: Path, log: Path) -> dict[str, ParamValue]:
    """Run ``calibrate_resonance BAG -o OUT``; return its ``resonance.*`` parameters.

    Raises:
        SelfSensingError: the tool failed (its last line) or wrote no parameters.

    """
    out.parent.mkdir(parents=True, exist_ok=True)
    with log.open("w") as handle:
        done = subprocess.run(
            [str(executable("es_thermal", "calibrate_resonance")), str(bag), "-o", str(out)],
            stdout=handle, stderr=subprocess.STDOUT, check=False,
        )  # fmt: skip
    if done.returncode != 0 or not out.is_file():
        tail = log.read_text(errors="replace").strip().splitlines()[-1:] or ["no output"]
        raise SelfSensingError(f"calibrate_resonance failed on {bag}: {tail[0]} (log: {log})")
    params = yaml.safe_load(out.read_text())["thermal"]["ros__parameters"]
    return {k: v for k, v in params.items() if str(k).startswith("resonance.")}


def temperature_errors(bag: Path, scenario: str, control_rate: float) -> FloatArray:
    """Return estimate - truth (Ns, R, C) [degC] of a closed-loop run's /dm/temperature.

    Raises:
        SelfSensingError: no estimate recorded.

    """
    sc = load_scenario(scenario).with_overrides(control_rate=control_rate)
    estimates = read_bag(bag, [_TEMPERATURE])[_TEMPERATURE].values
    if estimates is None or len(estimates) == 0:
        raise SelfSensingError(f"{bag}: no {_TEMPERATURE} recorded")
    plant = Plant(sc)
    truth = simulate(plant, commands=np.zeros(plant.steps))
    true_samples = truth.actuator_temperature[truth.sensor_step]
    count = min(len(estimates), len(true_samples))
    return np.asarray(estimates[:count] - true_samples[:count], float)


def case_figures(name: str, error: FloatArray, variation_m: float) -> CaseFigures:
    """Score a run's errors (Ns, R, C); the first :data:`SKIP_FRACTION` is the start-up."""
    scored = error[int(SKIP_FRACTION * len(error)) :]
    rms_map = np.sqrt(np.mean(scored**2, axis=0))
    return CaseFigures(
        name=name,
        rms_map=rms_map,
        rms=float(np.sqrt(np.mean(scored**2))),
        worst=float(np.max(rms_map)),
        max_error=float(np.max(np.abs(scored))),
        variation_m=variation_m,
    )


def plot_maps(cases: dict[str, CaseFigures], path: Path) -> None:
    """Plot every case's per-actuator RMS error map on one colour scale."""
    top = max(float(np.max(c.rms_map)) for c in cases.values())
    fig, axes = plt.subplots(1, len(cases), figsize=(4.2 * len(cases), 3.8), squeeze=False)
    image = None
    for ax, case in zip(axes[0], cases.values(), strict=True):
        image = ax.imshow(case.rms_map, vmin=0.0, vmax=top, cmap="viridis")
        ax.set_title(f"{CASE_TITLES[case.name]}\nRMS {case.rms:.3g} degC", fontsize=9)
        ax.set_xlabel("column")
    axes[0][0].set_ylabel("row")
    if image is not None:
        fig.colorbar(image, ax=axes[0].tolist(), label="RMS temperature error [degC]")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def section_markdown(
    cases: dict[str, CaseFigures], figure: str, params: dict[str, ParamValue], bags: dict[str, Path]
) -> str:
    """Return the report section: the table, the map figure and how it was made."""
    a, b, c = (cases[name] for name in CASES)
    ratio_a = a.rms / b.rms if b.rms > 0 else float("inf")
    ratio_c = b.variation_m / c.variation_m if c.variation_m > 0 else float("inf")
    f0_sd = np.asarray(params.get("resonance.f0_sd_hz", [np.nan]), float)
    noise = params.get("resonance.noise_hz")
    noise_hz = float(noise) if isinstance(noise, int | float) else float("nan")
    lines = [
        "## Self-sensing: every actuator its own thermometer",
        "",
        "The thickness-mode resonance (near 1 MHz) moves +3227 Hz/degC and -80 Hz/V (thesis "
        "table 3-2). A test stand of the 12 x 12 mirror with the resonance sweeps on was "
        "recorded and `calibrate_resonance` fitted f0, a_T and a_V per actuator (median f0 "
        f"uncertainty {np.median(f0_sd):.3g} Hz = {np.median(f0_sd) / 3227.0 * 1e3:.2g} mdegC; "
        f"reading noise {noise_hz:.3g} Hz). Then "
        f"`{SCENARIO}` (dipole exposure: a non-uniform heat load) ran in closed loop "
        "(`inverse_hyperbolic`, calibrated laws) with the same mirror and sweeps, the thermal "
        "node given (a) 4 NTCs, (b) the same 4 NTCs and the calibrated self-sensing, (c) an "
        "NTC on every actuator. Temperature error = /dm/temperature minus the simulator's "
        f"true actuator temperature, per sample after the first {SKIP_FRACTION:.0%} of the run.",
        "",
        "| case | RMS error | worst actuator (RMS) | largest error | variation |",
        "|---|---:|---:|---:|---:|",
    ]
    for case in (a, b, c):
        lines.append(
            f"| {CASE_TITLES[case.name]} | {case.rms:.4f} degC | {case.worst:.4f} degC | "
            f"{case.max_error:.3f} degC | {case.variation_m * 1e9:.3f} nm |"
        )
    lines += [
        "",
        f"(b) against (a): {ratio_a:.1f}x lower RMS error; (b)'s variation is {ratio_c:.2f}x "
        "(c)'s. Goals: RMS <= 0.02 degC, worst <= 0.05 degC, >= 5x better than (a), "
        "variation within 1.2x of (c).",
        "",
        f"![self-sensing temperature error maps]({figure})",
        "",
        "Bags: " + ", ".join(f"`{bag}`" for bag in bags.values()),
    ]
    return "\n".join(lines)
