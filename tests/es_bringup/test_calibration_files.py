"""es_bringup.calibration_files: the calibration's two files and who undoes the sensor lag.

One function decides the feedforward's temperature lead; the graph (a simulated scenario's
design lag too), the bring-up's command line and the launch file go through it. No node is
started here.
"""

from __future__ import annotations

import ast
from dataclasses import replace
from pathlib import Path

import pytest

from es_bringup.bringup import parse_args
from es_bringup.calibration_files import (
    FEEDFORWARD_FILE_NAME,
    LEAD_PARAMETER,
    THERMAL_FILE_NAME,
    CalibrationFiles,
    node_parameters,
    temperature_lead_s,
)
from es_bringup.errors import CalibrationFilesError
from es_bringup.graph import (
    FEEDFORWARD,
    THERMAL,
    GraphConfig,
    GraphError,
    ParamValue,
    build_graph,
)
from es_feedforward.compensation import CompensationParams
from es_feedforward.feedforward import FeedforwardConfig
from es_feedforward.param_file import write_params_file
from es_thermal.sensor_params import SensorCalibration, write_sensor_params

LAUNCH_FILE = Path(__file__).parents[2] / "src/es_bringup/launch/closed_loop.launch.py"
LEAD = 3.0


def _calibration(directory: Path, lag_s: float | None = 2.0, lead: float = LEAD) -> Path:
    """Write what ``calibrate -o directory`` writes (1 x 1 grid); ``lag_s`` None: no thermal."""
    directory.mkdir(parents=True, exist_ok=True)
    config = FeedforwardConfig(
        shape=(1, 1), compensation=replace(CompensationParams(), temperature_lead_s=lead)
    )
    write_params_file(directory / FEEDFORWARD_FILE_NAME, config)
    if lag_s is not None:
        write_sensor_params(directory / THERMAL_FILE_NAME, SensorCalibration(lag_s=lag_s))
    return directory


def test_the_lead_is_off_when_the_thermal_node_is_told_the_lag() -> None:
    feedforward = {LEAD_PARAMETER: LEAD}
    assert temperature_lead_s(feedforward, None) == LEAD  # temperature from elsewhere
    assert temperature_lead_s(feedforward, {"rows": 1}) == LEAD  # thermal node, no lag
    assert temperature_lead_s(feedforward, {"sensor_lag_tau": [2.0, 3.0]}) == 0.0
    assert temperature_lead_s(feedforward, {"sensor_lag_tau": 0.0}) == 0.0  # it owns it
    assert temperature_lead_s({}, None) == 0.0  # nothing calibrated
    with pytest.raises(CalibrationFilesError, match="temperature_lead_s"):
        temperature_lead_s({LEAD_PARAMETER: "x"}, None)


def test_the_files_decide_through_the_same_function(tmp_path: Path) -> None:
    directory = _calibration(tmp_path / "cal")
    files = CalibrationFiles.from_directory(directory)
    assert files == CalibrationFiles(directory / FEEDFORWARD_FILE_NAME,
                                     directory / THERMAL_FILE_NAME)
    feedforward = node_parameters(directory / FEEDFORWARD_FILE_NAME, FEEDFORWARD)
    thermal = node_parameters(directory / THERMAL_FILE_NAME, THERMAL)
    assert feedforward[LEAD_PARAMETER] == LEAD and thermal["sensor_lag_tau"] == 2.0
    assert temperature_lead_s(feedforward, thermal) == 0.0
    assert temperature_lead_s(feedforward, None) == LEAD


def _nodes(config: GraphConfig) -> dict[str, tuple[dict[str, object], tuple[Path, ...]]]:
    return {n.name: (dict(n.parameters), n.params_files) for n in build_graph(config).nodes}


def test_the_graph_passes_both_files_and_the_lead_they_give(tmp_path: Path) -> None:
    # thesis_ac without its design lag: the simulated plant's rule alone would keep the lead
    no_lag: dict[str, ParamValue] = {"effects.sensor_lag": False}
    directory = _calibration(tmp_path / "cal")
    files = CalibrationFiles.from_directory(directory)
    nodes = _nodes(GraphConfig(scenario="thesis_ac", plant=no_lag,
                               feedforward_params=files.feedforward,
                               thermal_params=files.thermal))
    thermal, thermal_files = nodes[THERMAL]
    feedforward, feedforward_files = nodes[FEEDFORWARD]
    assert thermal_files == (files.thermal,) and feedforward_files == (files.feedforward,)
    assert "sensor_lag_tau" not in thermal  # from the file, not overridden by -p
    assert feedforward[LEAD_PARAMETER] == 0.0
    # the feedforward's file alone: its calibrated lead on the raw-like temperature
    only = _nodes(GraphConfig(scenario="thesis_ac", plant=no_lag,
                              feedforward_params=files.feedforward))
    assert only[FEEDFORWARD][0][LEAD_PARAMETER] == LEAD and only[THERMAL][1] == ()
    # the scenario's design lag: the thermal node has it, the lead is off (same function)
    design = _nodes(GraphConfig(scenario="thesis_ac", feedforward_params=files.feedforward))
    assert design[FEEDFORWARD][0][LEAD_PARAMETER] == 0.0
    assert design[THERMAL][0]["sensor_lag_tau"] == pytest.approx(3.0)  # thesis_ac's
    # a calibrated lag wins over the design's (-p would win over the file)
    both = _nodes(GraphConfig(scenario="thesis_ac", feedforward_params=files.feedforward,
                              thermal_params=files.thermal))
    assert "sensor_lag_tau" not in both[THERMAL][0]


def test_a_namespaced_graph_gets_a_renamed_copy_of_the_thermal_file(tmp_path: Path) -> None:
    files = CalibrationFiles.from_directory(_calibration(tmp_path / "cal"))
    config = GraphConfig(scenario="thesis_ac", namespace="run0", log_dir=tmp_path / "logs",
                         feedforward_params=files.feedforward, thermal_params=files.thermal)
    (copy,) = _nodes(config)[THERMAL][1]
    assert node_parameters(copy, "/run0/thermal")["sensor_lag_tau"] == 2.0


def test_an_unreadable_thermal_file_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "thermal.yaml"
    path.write_text("not: [a parameters file")
    with pytest.raises(GraphError) as err:
        build_graph(GraphConfig(scenario="thesis_ac", thermal_params=path))
    assert "\n" not in str(err.value)


def test_the_command_line_takes_a_directory_or_the_files(tmp_path: Path) -> None:
    directory = _calibration(tmp_path / "cal")
    config, _ = parse_args(["--scenario", "thesis_ac", "--calibration", str(directory)])
    assert config.feedforward_params == directory / FEEDFORWARD_FILE_NAME
    assert config.thermal_params == directory / THERMAL_FILE_NAME
    config, _ = parse_args(["--scenario", "thesis_ac", "--thermal-params",
                            str(directory / THERMAL_FILE_NAME)])
    assert (config.feedforward_params, config.thermal_params) == (
        None, directory / THERMAL_FILE_NAME)
    # a calibration without a thermal file (an older one): the feedforward's only
    old = _calibration(tmp_path / "old", lag_s=None)
    config, _ = parse_args(["--scenario", "thesis_ac", "--calibration", str(old)])
    assert (config.feedforward_params, config.thermal_params) == (
        old / FEEDFORWARD_FILE_NAME, None)


@pytest.mark.parametrize(
    "arguments",
    [
        ["--calibration", "{d}", "--thermal-params", "{d}/thermal_params.yaml"],
        ["--calibration", "{d}/missing"],
        ["--thermal-params", "{d}/missing.yaml"],
    ],
)
def test_bad_calibration_arguments_exit_2_in_one_line(
    tmp_path: Path, arguments: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    directory = _calibration(tmp_path / "cal")
    with pytest.raises(SystemExit) as exit_:
        parse_args(["--scenario", "thesis_ac", *(a.format(d=directory) for a in arguments)])
    assert exit_.value.code == 2
    assert capsys.readouterr().err.strip().count("\n") == 0


def test_the_launch_file_takes_both_files_and_the_directory() -> None:
    tree = ast.parse(LAUNCH_FILE.read_text())
    assignment = next(
        node for node in tree.body
        if isinstance(node, ast.AnnAssign) and ast.unparse(node.target) == "ARGUMENTS"
    )  # fmt: skip
    assert assignment.value is not None
    names = {name for name, _, _ in ast.literal_eval(assignment.value)}
    assert {"feedforward_params", "thermal_params", "calibration"} <= names
    calls = {ast.unparse(n.func) for n in ast.walk(tree) if isinstance(n, ast.Call)}
    assert "CalibrationFiles.given" in calls
