"""The demo's test stands and calibrations: stand scenarios, sample-clock copies, the tool.

A test stand measures the hardware of a scenario (:func:`characterisation_scenario`), its bag
is copied with the sample clock's stamps (:func:`daq_clock_copy`), and ``es_feedforward
calibrate`` turns the copy into a parameters YAML (:func:`calibrate`). The calibration loop
(the demo's step 4) switches on an effect the model lacks (``LOOP_EFFECT``) and compares the
tracking with the parameters without and with its compensation (:func:`without_compensation`).
"""

from __future__ import annotations

import json
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import yaml

from es_bringup.bringup import executable
from es_bringup.calibration_files import CalibrationFiles
from es_bringup.demo_runs import DemoError
from es_bringup.errors import CalibrationFilesError
from es_sim_plant.plant import sensor_every
from es_sim_plant.scenario import load_scenario, resolve_scenario

#: Shipped test-stand scenario every characterisation is derived from.
CHARACTERISATION = "characterisation"
#: Effect switched on, undeclared, in the calibration loop: the actuator's own thermal
#: expansion (0.4 nm/degC), which no voltage model explains and which moves the output with
#: temperature exactly where the compensation must act.
LOOP_EFFECT = "thermal_expansion"
#: Scenario the calibration loop's before/after tracking runs on.
LOOP_SCENARIO = "thesis_ac"
#: Scenario keys a test stand copies from the scenario it characterises (same hardware).
HARDWARE_KEYS = ("grid", "seed", "thermal", "sensors", "actuators", "effects")


def _scenario_dict(name: str) -> dict[str, Any]:
    data = yaml.safe_load(resolve_scenario(name).read_text())
    if not isinstance(data, dict):
        raise DemoError(f"scenario {name} is not a YAML mapping")
    return data


def characterisation_scenario(
    scenario: str, out: Path, effects: dict[str, Any] | None = None, suffix: str = ""
) -> Path:
    """Write the characterisation of the hardware of ``scenario`` and return its path.

    The shipped ``characterisation`` scenario's program (voltage excitation, temperature
    ramp, interferometer noise) on the grid, seed, sensors, actuators and thermal set-up of
    ``scenario``: the same actuators with the same spread and the same sensors, as a test
    stand would measure the mirror it later controls. ``effects`` replaces the effects.
    """
    stand = _scenario_dict(CHARACTERISATION)
    source = _scenario_dict(scenario)
    for key in HARDWARE_KEYS:
        if key in source:
            stand[key] = source[key]
        else:
            stand.pop(key, None)
    if effects is not None:
        stand["effects"] = effects
    label = Path(scenario).stem  # a shipped name, or a scenario file's stem
    stand["name"] = f"{CHARACTERISATION}_{label}{suffix}"
    stand["description"] = f"test stand for the hardware of {label}{suffix}"
    path = out / f"{stand['name']}.yaml"
    path.write_text(yaml.safe_dump(stand, sort_keys=False))
    load_scenario(str(path))  # fail here, readably, if the combination is invalid
    return path


def scenario_with_effects(scenario: str, out: Path, effects: dict[str, Any], suffix: str) -> Path:
    """Write ``scenario`` with ``effects`` replaced and return its path."""
    data = _scenario_dict(scenario)
    data["effects"] = effects
    data["name"] = f"{scenario}{suffix}"
    path = out / f"{data['name']}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    load_scenario(str(path))
    return path


def daq_clock_copy(bag: Path, out: Path, scenario: str) -> Path:
    """Write a copy of a lockstep test-stand bag stamped by the sample clock; return it.

    A lab's DAQ stamps every sample with its sample clock. The recorder stamps messages with
    its sim clock at reception instead, and under load it falls behind the plant, so runs of
    messages share one stamp (reported to the recorder's owners). The lockstep protocol gives
    every message its exact time from its index: step k's command and displacement at
    t_k = k / control_rate, sensor sample j at step j * sensor_every. The calibration reads
    this copy; the messages themselves are unchanged.
    """
    from es_msgs_py.bag import read_bag, write_array_bag
    from es_msgs_py.topics import COMMAND, DISPLACEMENT, HEAT_LOAD, TEMPERATURE_RAW

    sc = load_scenario(scenario)
    every = sensor_every(sc.control_rate, sc.sensor_rate)
    data = read_bag(bag, [COMMAND, DISPLACEMENT, HEAT_LOAD, TEMPERATURE_RAW])
    series = {}
    steps = {COMMAND: 1, DISPLACEMENT: 1, HEAT_LOAD: every, TEMPERATURE_RAW: every}
    for topic, step in steps.items():
        values = data[topic].values
        assert values is not None
        series[topic] = (np.arange(len(values)) * step / sc.control_rate, values)
    write_array_bag(out, series)
    return out


#: calibrate's exit status for a trusted and a provisional result (both written files) ...
ACCEPTED_EXIT: Final = (0, 3)
#: ... and for an unusable one (the demo refuses it).
EXIT_UNUSABLE: Final = 4


def health_lines(summary: dict[str, Any]) -> list[str]:
    """Return the verdict and the health findings of a calibration.json, one line each."""
    verdict = summary.get("verdict") or {}
    reasons = "; ".join(map(str, verdict.get("reasons") or []))
    lines = [f"verdict: {verdict.get('level', 'none given')}" + (f" ({reasons})" if reasons
                                                                  else "")]
    findings = (summary.get("health") or {}).get("findings") or []
    lines += [f"health: {f.get('sentence', '?')} ({f.get('action', '?')})" for f in findings]
    if not findings:
        lines.append("health: no finding")
    return lines


@dataclass
class Calibrated:
    """Output of one calibration: parameters YAMLs and calibration.json content.

    ``params`` is the feedforward's file, ``thermal_params`` the thermal node's (None: the
    tool wrote none).
    """

    params: Path
    summary: dict[str, Any]
    report: Path
    wall_s: float
    thermal_params: Path | None = None


def calibrate(bag: Path, out_dir: Path, log: Path, time_scale: float = 1.0) -> Calibrated:
    """Run ``es_calibration calibrate BAG -o OUT_DIR`` and return what it wrote.

    ``time_scale``: the recording's (the stand scenario's), so that the thermal node's file
    holds physical lags.
    """
    started = time.monotonic()
    with log.open("w") as handle:
        result = subprocess.run(
            [str(executable("es_calibration", "calibrate")), str(bag), "-o", str(out_dir),
             "--time-scale", repr(float(time_scale))],
            stdout=handle,
            stderr=subprocess.STDOUT,
            check=False,
        )
    if result.returncode not in ACCEPTED_EXIT:
        tail = log.read_text(errors="replace").strip().splitlines()[-1:] or ["no output"]
        if result.returncode == EXIT_UNUSABLE:
            raise DemoError(f"calibrate judged {bag} unusable: {tail[0]} (log: {log})")
        raise DemoError(f"calibrate failed on {bag}: {tail[0]} (log: {log})")
    summary_file = out_dir / "calibration.json"
    try:
        files = CalibrationFiles.from_directory(out_dir)
    except CalibrationFilesError:
        files = None
    if files is None or files.feedforward is None or not summary_file.is_file():
        raise DemoError(f"calibrate wrote no parameters YAML or calibration.json in {out_dir}")
    reports = sorted(out_dir.glob("*.md"))
    return Calibrated(
        params=files.feedforward,
        summary=json.loads(summary_file.read_text()),
        report=reports[0] if reports else out_dir,
        wall_s=time.monotonic() - started,
        thermal_params=files.thermal,
    )


def without_compensation(params: Path, out: Path) -> Path:
    """Write a copy of a parameters YAML without its ``compensation.*`` entries."""
    data = yaml.safe_load(params.read_text())
    for node in data.values():
        ros = node.get("ros__parameters", {})
        for name in [n for n in ros if str(n).startswith("compensation.")]:
            del ros[name]
        compensation = ros.get("compensation")
        if isinstance(compensation, dict):
            del ros["compensation"]
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out


def hardware_signature(path: Path) -> str:
    """Return what makes two test stands measure the same hardware.

    Without manufacturing spread and sensor offsets the seed draws nothing but noise, so it
    does not tell two actuators apart.
    """
    sc = load_scenario(str(path))
    data = yaml.safe_load(path.read_text())
    keys = list(HARDWARE_KEYS)
    if not sc.actuators.spread and sc.sensors.offset_sd == 0 and sc.sensors.offsets is None:
        keys.remove("seed")
    return json.dumps({k: data.get(k) for k in keys}, sort_keys=True, default=str)
