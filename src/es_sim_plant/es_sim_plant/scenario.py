"""Scenario files: what a plant run simulates (grid, heat load, base temperature, set points).

A scenario is a YAML mapping (all keys optional except ``name``; SI units, degC)::

    name: dm_exposure            # identifier (file stem by convention)
    description: text
    grid: {rows: 12, cols: 12}
    control_rate: 100.0          # Hz, plant step = command period
    sensor_rate: 10.0            # Hz, /dm/temperature/raw and /dm/heat_load rate (divides
                                 #     control_rate: sampled every round(control/sensor) steps)
    duration: 600.0              # s, physical (multiplied by time_scale)
    time_scale: 0.05             # < 1 shortens every slow time (see below); 1 = physical
    seed: 1                      # spread, sensor offsets and noise, excitation phases
    thermal: {face_capacitance: .., ...}          # es_sim_plant.thermal.ThermalParams
    base_temperature:            # thermal-control (base plate) profile
      points: [[0, 42.0], [100, 44.0]]           # [t s, T degC], t physical (scaled)
      interpolation: linear      # or step
    illumination:                # absent or null: no UV (base-profile mode)
      pattern: dipole            # uniform | dipole | quadrupole | off_axis_spot | annular
      total_power_w: 1.0         # absorbed by the whole mirror while exposing
      offset: 0.6, sigma: 0.25, angle_deg: 0, spot_x: .., spot_y: .., background: 0.1
      schedule: {start_s: 0, exposure_s: 20, swap_s: 8, count: 0}   # times physical
    sensors: {positions: null, noise_sd: 0.02, resolution: 0.01, offset_sd: 0, offsets: null}
    actuators:
      params: {m2: 1504e-18, ...}          # es_physics.params.ActuatorParams fields
      spread: {m2: 0.02, k2: 0.01}         # relative standard deviation per field
      v_limit: 350.0
      substeps: 10                         # internal steps per plant step
    setpoint:                    # es_sim_plant.reference.SetpointSpec
      offset: 80.0e-9
      shape: {defocus: 40.0e-9, astig_0: 20.0e-9}
      sine: {amplitude: 5.0e-9, frequency: 1.0, phase_deg: 0}
    excitation: null             # test-stand voltage program instead of commands (reference.py)
    effects: {hysteresis: {enabled: true, weight: 0.1, threshold_v: 30}, delay: true, ...}
    displacement_noise: 0.0      # m rms added to the *measured* displacement (interferometer)
    resonance: {enabled: false, group_size: 48, ...}  # self-sensing sweeps (resonance.py)

``time_scale`` multiplies the duration, the exposure schedule, the base-temperature profile
times, the thermal capacitances (so every thermal time constant) and the slow effect times
(``sensor_lag.tau_s``, ``drift.tau_s``); it does not touch set-point or excitation frequencies,
the delay, the rates or ``excitation.level_s``. The shipped scenarios are short versions of
physical runs; ``time_scale: 1`` (node parameter ``time_scale``) gives the physical length.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from es_sim_plant.actuators import ActuatorConfig
from es_sim_plant.effects import Effects
from es_sim_plant.errors import ScenarioError
from es_sim_plant.reference import Excitation, SetpointSpec
from es_sim_plant.resonance import ResonanceConfig
from es_sim_plant.sensors import SensorConfig
from es_sim_plant.thermal import BaseProfile, ExposureSchedule, Illumination, ThermalParams

PACKAGE = "es_sim_plant"
_TOP_KEYS = {
    "name", "description", "grid", "control_rate", "sensor_rate", "duration", "time_scale",
    "seed", "thermal", "base_temperature", "illumination", "sensors", "actuators", "setpoint",
    "excitation", "effects", "displacement_noise", "resonance",
}  # fmt: skip


@dataclass(frozen=True)
class Scenario:
    """A loaded scenario with ``time_scale`` already applied (every time is simulation time).

    Build with :func:`load_scenario` or :meth:`from_dict`; adjust with :meth:`with_overrides`.
    """

    name: str
    description: str = ""
    rows: int = 1
    cols: int = 1
    control_rate: float = 100.0
    sensor_rate: float = 10.0
    duration: float = 10.0
    time_scale: float = 1.0
    seed: int = 0
    thermal: ThermalParams = field(default_factory=ThermalParams)
    base: BaseProfile = field(default_factory=BaseProfile)
    illumination: Illumination | None = None
    schedule: ExposureSchedule = field(default_factory=ExposureSchedule)
    sensors: SensorConfig = field(default_factory=SensorConfig)
    actuators: ActuatorConfig = field(default_factory=ActuatorConfig)
    setpoint: SetpointSpec = field(default_factory=SetpointSpec)
    excitation: Excitation | None = None
    effects: Effects = field(default_factory=Effects)
    displacement_noise: float = 0.0
    resonance: ResonanceConfig = field(default_factory=ResonanceConfig)

    @property
    def shape(self) -> tuple[int, int]:
        """The grid shape (R, C)."""
        return (self.rows, self.cols)

    @property
    def initial_base_temperature(self) -> float:
        """T_b at t = 0 [degC] (also the thermal-expansion reference T_ref)."""
        return self.base.at(0.0)

    def validate(self) -> None:
        """Raise ``ScenarioError`` with a readable reason when a value is out of range."""
        if self.rows < 1 or self.cols < 1:
            raise ScenarioError("grid rows and cols must be >= 1")
        if not self.control_rate > 0.0 or not self.sensor_rate > 0.0:
            raise ScenarioError("control_rate and sensor_rate must be > 0")
        if self.sensor_rate > self.control_rate:
            raise ScenarioError("sensor_rate must not exceed control_rate")
        if not self.duration > 0.0:
            raise ScenarioError("duration must be > 0")
        if not self.time_scale > 0.0:
            raise ScenarioError("time_scale must be > 0")
        if self.displacement_noise < 0.0:
            raise ScenarioError("displacement_noise must be >= 0")
        self.thermal.validate()
        self.base.validate()
        self.schedule.validate()
        if self.illumination is not None:
            self.illumination.validate()
        self.actuators.validate()
        self.effects.validate()
        self.resonance.validate()

    @classmethod
    def from_dict(cls, data: dict[str, Any], time_scale: float | None = None) -> Scenario:
        """Build from a parsed YAML mapping; ``time_scale`` overrides the file's value.

        Raises:
            ScenarioError: unknown keys, wrong types or out-of-range values (readable reason).

        """
        if not isinstance(data, dict):
            raise ScenarioError("a scenario must be a YAML mapping")
        unknown = set(data) - _TOP_KEYS
        if unknown:
            raise ScenarioError(f"unknown scenario key(s) {sorted(unknown)}")
        if "name" not in data:
            raise ScenarioError("a scenario needs a 'name'")
        try:
            scale = float(time_scale if time_scale is not None else data.get("time_scale", 1.0))
            if not scale > 0.0:
                raise ScenarioError("time_scale must be > 0")
            grid = data.get("grid") or {}
            base_raw = data.get("base_temperature") or {}
            points = base_raw.get("points", [[0.0, 42.0]])
            base = BaseProfile(
                times=tuple(float(p[0]) for p in points),
                temperatures=tuple(float(p[1]) for p in points),
                interpolation=str(base_raw.get("interpolation", "linear")),
            )
            illumination: Illumination | None = None
            schedule = ExposureSchedule()
            illum_raw = data.get("illumination")
            if illum_raw:
                illum = dict(illum_raw)
                sched_raw = dict(illum.pop("schedule", None) or {})
                sched_values: dict[str, Any] = {
                    k: (int(v) if k == "count" else float(v)) for k, v in sched_raw.items()
                }
                schedule = ExposureSchedule(**sched_values)
                illum_values: dict[str, Any] = {
                    k: (str(v) if k == "pattern" else float(v)) for k, v in illum.items()
                }
                illumination = Illumination(**illum_values)
            excitation_raw = data.get("excitation")
            scenario = cls(
                name=str(data["name"]),
                description=str(data.get("description", "")),
                rows=int(grid.get("rows", 1)),
                cols=int(grid.get("cols", 1)),
                control_rate=float(data.get("control_rate", 100.0)),
                sensor_rate=float(data.get("sensor_rate", 10.0)),
                duration=float(data.get("duration", 10.0)) * scale,
                time_scale=scale,
                seed=int(data.get("seed", 0)),
                thermal=ThermalParams.from_dict(data.get("thermal")).time_scaled(scale),
                base=base.time_scaled(scale),
                illumination=illumination,
                schedule=schedule.time_scaled(scale),
                sensors=SensorConfig.from_dict(data.get("sensors")),
                actuators=ActuatorConfig.from_dict(data.get("actuators")),
                setpoint=SetpointSpec.from_dict(data.get("setpoint")),
                excitation=Excitation.from_dict(excitation_raw) if excitation_raw else None,
                effects=Effects.from_dict(data.get("effects")).time_scaled(scale),
                displacement_noise=float(data.get("displacement_noise", 0.0)),
                resonance=ResonanceConfig.from_dict(data.get("resonance")),
            )
        except (TypeError, KeyError, IndexError, AttributeError) as err:
            raise ScenarioError(f"malformed scenario ({type(err).__name__}: {err})") from None
        scenario.validate()
        return scenario

    def with_overrides(
        self,
        *,
        rows: int | None = None,
        cols: int | None = None,
        control_rate: float | None = None,
        sensor_rate: float | None = None,
        duration: float | None = None,
        seed: int | None = None,
        effects: dict[str, bool] | None = None,
        displacement_noise: float | None = None,
    ) -> Scenario:
        """Return a copy with the given values replaced (``None`` keeps the scenario's).

        ``duration`` is simulation time (already scaled); ``effects`` switches effects on or
        off by canonical name. Raises ``ScenarioError`` on out-of-range results.
        """
        changes: dict[str, Any] = {
            k: v
            for k, v in {
                "rows": rows,
                "cols": cols,
                "control_rate": control_rate,
                "sensor_rate": sensor_rate,
                "duration": duration,
                "seed": seed,
                "displacement_noise": displacement_noise,
            }.items()
            if v is not None
        }
        if effects:
            changes["effects"] = self.effects.with_switches(effects)
        scenario = replace(self, **changes)
        scenario.validate()
        return scenario


def scenario_dirs() -> list[Path]:
    """Return where scenario names are looked up, first match wins.

    The installed ``share/es_sim_plant/scenarios`` of this Python's prefix, the ament index's
    share directory when ament_index_python is available, then the source tree.
    """
    dirs = [Path(sys.prefix) / "share" / PACKAGE / "scenarios"]
    try:
        from ament_index_python.packages import get_package_share_directory

        dirs.append(Path(get_package_share_directory(PACKAGE)) / "scenarios")
    except Exception:  # not installed through ament: skip that location
        pass
    dirs.append(Path(__file__).resolve().parents[1] / "scenarios")
    return dirs


def available_scenarios() -> list[str]:
    """Return the names of the shipped scenarios found in :func:`scenario_dirs`."""
    names = {p.stem for d in scenario_dirs() if d.is_dir() for p in d.glob("*.yaml")}
    return sorted(names)


def resolve_scenario(name_or_path: str) -> Path:
    """Return the file of a scenario given as a path or as a shipped scenario's name.

    Raises:
        ScenarioError: neither an existing file nor a known name.

    """
    path = Path(name_or_path).expanduser()
    if path.suffix in (".yaml", ".yml") or path.is_file():
        if path.is_file():
            return path
        raise ScenarioError(f"scenario file {str(path)!r} does not exist")
    for directory in scenario_dirs():
        candidate = directory / f"{name_or_path}.yaml"
        if candidate.is_file():
            return candidate
    raise ScenarioError(
        f"unknown scenario {name_or_path!r}; shipped: {', '.join(available_scenarios()) or 'none'}"
    )


def load_scenario(name_or_path: str, time_scale: float | None = None) -> Scenario:
    """Load a scenario by shipped name or YAML path; ``time_scale`` overrides the file's.

    Raises:
        ScenarioError: missing file, YAML syntax error or invalid content (one readable line).

    """
    path = resolve_scenario(name_or_path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ScenarioError(f"cannot read scenario {str(path)!r}: {first}") from None
    try:
        return Scenario.from_dict(data, time_scale=time_scale)
    except ValueError as err:
        raise ScenarioError(f"scenario {str(path)!r}: {err}") from None
