"""The closed-loop node graph, described once: what ``bringup`` and ``closed_loop.launch.py`` run.

Pure (no rclpy, no launch): from a scenario and options, :func:`build_graph` returns every
node to start (package, executable, name, parameters, parameter files, program arguments)
with everything derived from the scenario: the grid, the thermal node's sensors, noise, lag
and network, the time scale. ``ros2 run es_bringup bringup`` turns the nodes into
supervised processes, ``ros2 launch es_bringup closed_loop.launch.py`` into launch_ros
``Node`` actions; both start the same graph.

The plant starts its scenario only when the recorder, thermal and feedforward nodes report
``"<node>: ready"`` on /diagnostics (plant parameter ``wait_ready``), not after a fixed
settle time: the controllers have matched their inputs, the recorder every /dm topic. A
calibrated feedforward parameters file is checked at build time: its grid (``rows``/``cols``)
must be the scenario's, else :class:`GraphError` says so in one line. A calibration's thermal
parameters file goes to the thermal node; which of the two undoes the sensor's lag is
decided once (:func:`es_bringup.calibration_files.temperature_lead_s`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Final

from es_bringup.calibration_files import LEAD_PARAMETER, node_parameters, temperature_lead_s
from es_bringup.errors import CalibrationFilesError
from es_msgs_py import topics
from es_node_runtime.param_yaml import dump_parameters, floats_from_strings

ParamValue = bool | int | float | str | list[float] | list[int] | list[str]

#: Node names (the defaults of the node executables; parameter files use them).
PLANT, THERMAL, FEEDFORWARD, RECORDER = "plant", "thermal", "feedforward", "record"

#: Topics the graph records: every /dm topic and /diagnostics.
RECORDED_TOPICS: Final[tuple[str, ...]] = (*topics.DM_TOPICS, topics.DIAGNOSTICS)
#: A test stand has no thermal node and no set points: its bag holds what a lab records.
TEST_STAND_TOPICS: Final[tuple[str, ...]] = tuple(
    t for t in RECORDED_TOPICS if t not in (topics.TEMPERATURE, topics.SETPOINT)
)
#: Recorder queue depth of a test stand: the whole backlog of a fast plant fits.
TEST_STAND_QUEUE_DEPTH: Final = 200_000
#: Most memory a recorder's queue may hold per topic in a closed loop [bytes]. The lockstep
#: plant is paced by the controllers, not by the recorder, and at small grids it outruns a
#: busy recorder (83 and 400 of 3001 messages lost with the contract-sized queue of 1000 in
#: the lockstep fault test on a loaded machine): the queue holds the backlog instead, reached
#: only while the recorder lags.
CLOSED_LOOP_QUEUE_BYTES: Final = 1 << 30
#: Speed limit of a test stand (x real time): measured here, a recorder keeps up with 250 Hz
#: test stands at 3x (no loss), the plant alone runs near 10x; the rest is caught up after
#: the run from the recorder's deep queue.
TEST_STAND_SPEED: Final = 5.0
#: The plant's and the thermal node's executor (``executor`` parameter) in a graph without a
#: recorder: the EventsExecutor, about half their CPU per lockstep step.
FAST_EXECUTOR: Final = "events"
#: Their executor in a graph with a recorder: a lockstep plant on the EventsExecutor outran
#: the recorder at 3 x 3 (400 of 3001 displacements lost in one of the fault test's runs; the
#: recorder keeps up with a few hundred steps per second, see TEST_STAND_SPEED).
RECORDED_EXECUTOR: Final = "single_threaded"
#: Longest wall time [s] the plant waits at its start for its peers to be ready (a 32 x 32
#: thermal estimator takes seconds to build on a busy machine).
START_TIMEOUT_S: Final = 120.0


class GraphError(ValueError):
    """The graph cannot be built as asked (one readable line)."""


@dataclass
class GraphConfig:
    """What the graph runs.

    Attributes:
        scenario: scenario name (shipped with es_sim_plant) or path to a scenario YAML.
        mode: feedforward mode.
        bag: bag directory to record into (must not exist), or ``None`` for no recorder.
        log_dir: directory for the node logs (and a namespaced copy of a parameters file).
        feedforward_params: ROS parameters YAML for the feedforward node (e.g. calibrated).
        thermal_params: ROS parameters YAML for the thermal node (a calibration's
            ``thermal_params.yaml``: the sensors' lag and offsets); its values win over the
            scenario's design values of the same names.
        plant / thermal / feedforward: extra parameters per node (override the defaults).
        storage: bag storage, ``mcap`` or ``sqlite3``.
        with_controllers: start the thermal and feedforward nodes; ``False`` runs the plant
            alone with the recorder (a test-stand characterisation drives its own voltages).
        domain_id: ROS_DOMAIN_ID of this run (``None``: inherit the environment's), so that
            runs can go in parallel without seeing each other.
        ready_timeout: wall seconds to wait for the nodes' subscriptions before the plant.
        namespace: run the graph below ``/<namespace>`` (topics remapped; bags keep the
            contract's topic names), so that several graphs share one ROS domain.
        wall_timeout: wall seconds after which the run is stopped as failed (``None``: none).
        duration: run length in simulation seconds (``None``: the scenario's).
        time_scale: multiplier of the scenario's slow times (``None``: the scenario's own).
        record_extra: further topics the recorder records (e.g. the optional /dm/resonance).

    """

    scenario: str
    mode: str = "inverse_hyperbolic"
    bag: Path | None = None
    log_dir: Path = Path("log/bringup")
    feedforward_params: Path | None = None
    thermal_params: Path | None = None
    plant: dict[str, ParamValue] = field(default_factory=dict)
    thermal: dict[str, ParamValue] = field(default_factory=dict)
    feedforward: dict[str, ParamValue] = field(default_factory=dict)
    storage: str = "mcap"
    with_controllers: bool = True
    domain_id: int | None = None
    ready_timeout: float = 30.0
    namespace: str | None = None
    wall_timeout: float | None = None
    duration: float | None = None
    time_scale: float | None = None
    record_extra: tuple[str, ...] = ()


@dataclass(frozen=True)
class NodeSpec:
    """One node of the graph, as ``ros2 run PACKAGE EXECUTABLE ARGUMENTS --ros-args ...``.

    Attributes:
        package / executable: what to run (``lib/<package>/<executable>``).
        name: node name.
        parameters: ``-p`` parameters (after the files: they win).
        params_files: ``--params-file`` files, in order.
        arguments: program arguments before ``--ros-args`` (the recorder's).

    """

    package: str
    executable: str
    name: str
    parameters: dict[str, ParamValue]
    params_files: tuple[Path, ...] = ()
    arguments: tuple[str, ...] = ()


@dataclass(frozen=True)
class Graph:
    """The nodes started before the plant (recorder first) and the plant."""

    before: list[NodeSpec]
    plant: NodeSpec
    namespace: str | None = None

    @property
    def nodes(self) -> list[NodeSpec]:
        """Every node, the plant last."""
        return [*self.before, self.plant]


def scoped(topic: str, namespace: str | None) -> str:
    """Return ``topic`` as a graph in ``namespace`` sees it (unchanged without one)."""
    return f"/{namespace}{topic}" if namespace else topic


def topic_remaps(namespace: str | None) -> list[tuple[str, str]]:
    """Return the remappings that put every contract topic below ``namespace`` (none without).

    Contract topics are absolute (/clock and /diagnostics too), so a node namespace alone
    does not move them.
    """
    if not namespace:
        return []
    return [(t, scoped(t, namespace)) for t in topics.TOPIC_TYPES]


def _plant_values(config: GraphConfig) -> dict[str, ParamValue]:
    """Return the plant's own overrides with the graph's duration and time scale folded in."""
    values: dict[str, ParamValue] = {}
    if config.duration is not None:
        values["duration"] = float(config.duration)
    if config.time_scale is not None:
        values["time_scale"] = float(config.time_scale)
    return {**values, **config.plant}


def build_graph(config: GraphConfig) -> Graph:
    """Return the nodes of the graph ``config`` describes.

    Raises:
        GraphError: the scenario cannot be loaded, or the feedforward parameters file is
            unreadable, invalid or made for another grid than the scenario's.

    """
    sim_time: dict[str, ParamValue] = {"use_sim_time": True}
    plant_values = _plant_values(config)
    before: list[NodeSpec] = []
    if config.bag is not None:
        recorded = (
            *(RECORDED_TOPICS if config.with_controllers else TEST_STAND_TOPICS),
            *config.record_extra,
        )
        depth = (
            closed_loop_queue_depth(*_grid(config.scenario, plant_values))
            if config.with_controllers
            else TEST_STAND_QUEUE_DEPTH
        )
        before.append(
            NodeSpec(
                "es_recordings", "record", RECORDER, dict(sim_time),
                arguments=("-o", str(config.bag), "--storage", config.storage,
                           "--queue-depth", str(depth), *recorded),
            )
        )  # fmt: skip
    if config.with_controllers:
        before += _controller_specs(config, plant_values)
    plant_params: dict[str, ParamValue] = {
        "scenario": config.scenario,
        "lockstep": True,
        "exit_when_done": True,
        "start_timeout": START_TIMEOUT_S,
        # the scenario starts once the other nodes say they have their inputs
        "wait_ready": [spec.name for spec in before],
        # without a thermal node there is no /dm/temperature to wait for, and no controller
        # paces the plant: it runs at a speed the recorder keeps up with
        **(
            {}
            if config.with_controllers
            else {"sync_temperature": False, "max_speed": TEST_STAND_SPEED}
        ),
        # the recorder's subscriptions must match before the first message goes out
        **({"start_subscribers": 1} if config.bag is not None else {}),
        "executor": FAST_EXECUTOR if config.bag is None else RECORDED_EXECUTOR,
        # the thermal node and the feedforward both count the raw samples
        **(
            {"raw_subscribers": 2}
            if config.with_controllers and _synchronised(plant_values)
            else {}
        ),
        **plant_values,
    }
    plant = NodeSpec("es_sim_plant", "plant_node", PLANT, plant_params)
    return Graph(before, plant, config.namespace)


def closed_loop_queue_depth(rows: int, cols: int) -> int:
    """Return the recorder's queue depth per topic in a closed loop of ``rows`` x ``cols``.

    As deep as a test stand's, within CLOSED_LOOP_QUEUE_BYTES of grid messages, never below
    the /dm topics' own depth.
    """
    message_bytes = 8 * rows * cols + 64  # the doubles and the layout
    fits = CLOSED_LOOP_QUEUE_BYTES // message_bytes
    return max(topics.DM_DEPTH, min(TEST_STAND_QUEUE_DEPTH, fits))


def _grid(scenario: str, plant_values: Mapping[str, ParamValue]) -> tuple[int, int]:
    """Return the plant's (rows, cols): the scenario's with the plant's overrides."""
    thermal, _ = scenario_parameters(scenario, plant_values)
    rows, cols = thermal["rows"], thermal["cols"]
    assert isinstance(rows, int) and isinstance(cols, int)
    return rows, cols


def _synchronised(plant_values: Mapping[str, ParamValue]) -> bool:
    """Return whether the plant waits for each sample's estimate (lockstep, the default)."""
    return bool(plant_values.get("lockstep", True)) and bool(
        plant_values.get("sync_temperature", True)
    )


def _file_values(path: Path | None, node: str) -> dict[str, object]:
    """Return the parameters ``path`` gives ``node`` (empty without a file).

    Raises:
        GraphError: the file cannot be read.

    """
    if path is None:
        return {}
    try:
        return node_parameters(path, node)
    except CalibrationFilesError as err:
        raise GraphError(f"{node} parameters: {err}") from None


def _controller_specs(
    config: GraphConfig, plant_values: Mapping[str, ParamValue]
) -> list[NodeSpec]:
    sim_time: dict[str, ParamValue] = {"use_sim_time": True}
    thermal_file = _file_values(config.thermal_params, THERMAL)
    thermal, feedforward = scenario_parameters(
        config.scenario, plant_values, _file_values(config.feedforward_params, FEEDFORWARD),
        {**thermal_file, **config.thermal},
    )
    # the thermal file's values win over the scenario's design (-p would win over a file)
    thermal = {k: v for k, v in thermal.items() if k not in thermal_file}
    files: tuple[Path, ...] = ()
    if config.feedforward_params is not None:
        rows, cols = thermal["rows"], thermal["cols"]
        assert isinstance(rows, int) and isinstance(cols, int)
        check_params_grid(config.feedforward_params, (rows, cols))
        path = config.feedforward_params
        if config.namespace:
            path = namespaced_params_file(path, FEEDFORWARD, config)
        files = (path,)
    thermal_files: tuple[Path, ...] = ()
    if config.thermal_params is not None:
        path = config.thermal_params
        if config.namespace:
            path = namespaced_params_file(path, THERMAL, config)
        thermal_files = (path,)
    # Readiness includes the first message reaching every subscriber of the graph (DDS
    # matching is one-sided: the recorder's match alone does not say the publisher's side has
    # matched it): estimates go to the feedforward, the lockstep plant and the recorder,
    # commands to the plant and the recorder.
    recorder = int(config.bag is not None)
    synced = int(_synchronised(plant_values))
    thermal["ready_subscribers"] = 1 + synced + recorder
    feedforward["ready_subscribers"] = 1 + recorder
    # In lockstep the feedforward holds a set point until the step's estimate is in (the two
    # come from different publishers, which DDS does not order).
    feedforward["sync_temperature"] = bool(synced)
    # without a recorder the thermal node's own default (events; single-threaded with
    # self-sensing, which cannot run on events)
    executor: dict[str, ParamValue] = {} if recorder == 0 else {"executor": RECORDED_EXECUTOR}
    return [
        NodeSpec(
            "es_thermal", "thermal_node", THERMAL,
            {**sim_time, **thermal, **executor, **config.thermal}, thermal_files,
        ),
        NodeSpec(
            "es_feedforward",
            "feedforward_node",
            FEEDFORWARD,
            {**sim_time, **feedforward, "mode": config.mode, **config.feedforward},
            files,
        ),
    ]


def check_params_grid(path: Path, grid: tuple[int, int]) -> None:
    """Check that a feedforward parameters file is valid, usable and made for ``grid``.

    Raises:
        GraphError: unreadable or invalid file, a calibration verdict "unusable", or a grid
            other than ``grid`` (rows, cols).

    """
    from es_feedforward.param_file import read_params_file, read_params_verdict

    try:
        shape = read_params_file(path).shape
        verdict, reasons = read_params_verdict(path)
    except ValueError as err:
        raise GraphError(f"feedforward parameters: {err}") from None
    if verdict == "unusable":
        because = "; ".join(reasons) or "no reason given"
        raise GraphError(
            f"feedforward parameters {path}: the calibration judged them unusable "
            f"({because}): recalibrate"
        )
    if shape != grid:
        raise GraphError(
            f"feedforward parameters {path} are for a {shape[0]} x {shape[1]} grid, the "
            f"scenario's is {grid[0]} x {grid[1]}: calibrate for this grid or pick a "
            "matching scenario"
        )


def scenario_parameters(
    scenario: str,
    plant: Mapping[str, ParamValue],
    feedforward_file: Mapping[str, object] | None = None,
    thermal_given: Mapping[str, object] | None = None,
) -> tuple[dict[str, ParamValue], dict[str, ParamValue]]:
    """Return the thermal and feedforward parameters that describe the plant's mirror.

    Read from the scenario with the plant's own overrides (``rows``, ``cols``,
    ``time_scale``, ``sensor_rate``, ``effects.sensor_lag``), so that the three nodes agree
    on the grid, the sensors and the time scale. The thermal node gets what the mirror's
    design tells: the thermal network (physical values; it applies ``time_scale`` itself as
    the plant does), the sensor positions, rate, noise level and lag (``sensor_lag_tau``,
    physical: a property of the sensor as mounted). The feedforward gets
    ``compensation.temperature_lead_s`` from
    :func:`es_bringup.calibration_files.temperature_lead_s`, given the feedforward's file
    (``feedforward_file``, its parameters) and the thermal node's parameters (these and
    ``thermal_given``: a calibration's thermal file and explicit overrides): 0 when the
    thermal node is told the lag (its estimate is then of the actuator, the lag is undone
    once), else the file's calibrated lead. Nothing else the calibration is meant to find
    (the actuator laws, effects) is passed.

    Raises:
        GraphError: the scenario cannot be loaded, or the feedforward file's lead is not a
            number.

    """
    from es_sim_plant.scenario import load_scenario

    def number(name: str) -> float:
        value = plant.get(name, 0)
        return float(value) if isinstance(value, int | float) else 0.0

    try:
        scaled = load_scenario(scenario, number("time_scale") or None)
        physical = load_scenario(scenario, 1.0)
    except ValueError as err:
        raise GraphError(str(err).splitlines()[0]) from None
    rows = int(number("rows")) or scaled.rows
    cols = int(number("cols")) or scaled.cols
    sensor_rate = number("sensor_rate") or scaled.sensor_rate
    grid: dict[str, ParamValue] = {"rows": rows, "cols": cols}
    thermal: dict[str, ParamValue] = {
        **grid,
        "sample_rate": sensor_rate,
        "time_scale": scaled.time_scale,
        "model.sensor_noise": max(scaled.sensors.noise_sd, 1e-6),
        **{f"thermal.{k}": float(v) for k, v in asdict(physical.thermal).items()},
    }
    if plant.get("effects.sensor_lag", physical.effects.sensor_lag.enabled) is True:
        thermal["sensor_lag_tau"] = physical.effects.sensor_lag.tau_s
    if scaled.sensors.positions is not None:
        thermal["sensor_positions"] = [float(v) for p in scaled.sensors.positions for v in p]
    try:
        lead = temperature_lead_s(feedforward_file or {}, {**thermal, **(thermal_given or {})})
    except CalibrationFilesError as err:
        raise GraphError(str(err)) from None
    feedforward: dict[str, ParamValue] = {**grid, LEAD_PARAMETER: lead}
    return thermal, feedforward


def namespaced_params_file(path: Path, node: str, config: GraphConfig) -> Path:
    """Return a copy of a parameters file whose entries for ``node`` apply below the namespace.

    A parameters file names the node it configures by its full name (``feedforward`` is
    ``/feedforward``); in a namespaced graph the node is ``/<namespace>/feedforward``. The
    copy goes into ``config.log_dir``; its floats are written so that every ROS 2 reader
    reads them as floats (:mod:`es_node_runtime.param_yaml`).

    Raises:
        GraphError: the file is no ROS 2 parameters file.

    """
    import yaml

    try:
        data, _ = floats_from_strings(yaml.safe_load(path.read_text(encoding="utf-8")))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise GraphError(f"cannot read parameters file {path}: {err}".splitlines()[0]) from None
    if not isinstance(data, dict):
        raise GraphError(f"{path} is not a ROS 2 parameters file")
    renamed = {
        (f"/{config.namespace}/{node}" if key.strip("/") == node else key): value
        for key, value in data.items()
    }
    config.log_dir.mkdir(parents=True, exist_ok=True)
    copy = config.log_dir / f"{node}_params.yaml"
    copy.write_text(dump_parameters(renamed), encoding="utf-8")
    return copy
