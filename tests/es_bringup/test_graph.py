"""es_bringup.graph: one description of the graph for bringup and ros2 launch."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from es_bringup.bringup import node_specs
from es_bringup.graph import (
    FAST_EXECUTOR,
    FEEDFORWARD,
    PLANT,
    RECORDED_EXECUTOR,
    RECORDER,
    TEST_STAND_QUEUE_DEPTH,
    THERMAL,
    GraphConfig,
    GraphError,
    build_graph,
    closed_loop_queue_depth,
    topic_remaps,
)
from es_feedforward.feedforward import FeedforwardConfig
from es_feedforward.param_file import write_params_file
from es_msgs_py import topics
from es_sim_plant.scenario import load_scenario

LAUNCH_FILE = Path(__file__).parents[2] / "src/es_bringup/launch/closed_loop.launch.py"


def by_name(config: GraphConfig) -> dict[str, dict[str, object]]:
    return {node.name: dict(node.parameters) for node in build_graph(config).nodes}


def test_every_node_gets_the_scenario_grid_sensors_lag_and_time_scale() -> None:
    nodes = by_name(GraphConfig(scenario="thesis_ac", bag=Path("bag")))
    scenario = load_scenario("thesis_ac")
    physical = load_scenario("thesis_ac", 1.0)
    assert list(nodes) == [RECORDER, THERMAL, FEEDFORWARD, PLANT]
    grid = {"rows": scenario.rows, "cols": scenario.cols}
    assert {k: nodes[THERMAL][k] for k in grid} == grid
    assert {k: nodes[FEEDFORWARD][k] for k in grid} == grid
    assert nodes[THERMAL]["time_scale"] == scenario.time_scale
    assert nodes[THERMAL]["sample_rate"] == scenario.sensor_rate
    assert nodes[THERMAL]["sensor_lag_tau"] == physical.effects.sensor_lag.tau_s
    assert nodes[FEEDFORWARD]["compensation.temperature_lead_s"] == 0.0
    assert nodes[PLANT]["wait_ready"] == [RECORDER, THERMAL, FEEDFORWARD]
    assert nodes[PLANT]["start_subscribers"] == 1
    # first estimate to feedforward, plant and recorder; first command to plant and recorder
    assert (nodes[THERMAL]["ready_subscribers"], nodes[FEEDFORWARD]["ready_subscribers"]) == (3, 2)
    # in lockstep the feedforward waits for each raw sample's estimate, so it counts the raw
    # samples too, and the plant waits for both controllers' raw subscriptions
    assert nodes[FEEDFORWARD]["sync_temperature"] is True
    assert nodes[PLANT]["raw_subscribers"] == 2
    assert all(nodes[n]["use_sim_time"] is True for n in (RECORDER, THERMAL, FEEDFORWARD))


def test_duration_time_scale_and_grid_overrides_reach_every_node() -> None:
    config = GraphConfig(
        scenario="dm_exposure", duration=4.0, time_scale=0.1, plant={"rows": 4, "cols": 5}
    )
    nodes = by_name(config)
    assert (nodes[PLANT]["duration"], nodes[PLANT]["time_scale"]) == (4.0, 0.1)
    assert nodes[THERMAL]["time_scale"] == 0.1
    assert (nodes[THERMAL]["rows"], nodes[THERMAL]["cols"]) == (4, 5)
    assert (nodes[FEEDFORWARD]["rows"], nodes[FEEDFORWARD]["cols"]) == (4, 5)
    assert RECORDER not in nodes  # no bag, no recorder
    assert nodes[PLANT]["wait_ready"] == [THERMAL, FEEDFORWARD]
    assert (nodes[THERMAL]["ready_subscribers"], nodes[FEEDFORWARD]["ready_subscribers"]) == (2, 1)


def test_a_real_time_plant_is_no_subscriber_the_thermal_node_waits_for() -> None:
    # a free-running plant does not subscribe to /dm/temperature (the soak runs this way)
    nodes = by_name(GraphConfig(scenario="dm_exposure", bag=Path("b"),
                                plant={"lockstep": False}))  # fmt: skip
    assert (nodes[THERMAL]["ready_subscribers"], nodes[FEEDFORWARD]["ready_subscribers"]) == (2, 2)
    # nothing to wait for: the plant does not wait for the estimates either
    assert nodes[FEEDFORWARD]["sync_temperature"] is False
    assert "raw_subscribers" not in nodes[PLANT]


def test_the_plant_and_thermal_node_spin_on_events_only_without_a_recorder() -> None:
    unrecorded = by_name(GraphConfig(scenario="dm_exposure"))
    assert unrecorded[PLANT]["executor"] == FAST_EXECUTOR == "events"
    assert "executor" not in unrecorded[THERMAL]  # its own default (self-sensing: threaded)
    recorded = by_name(GraphConfig(scenario="dm_exposure", bag=Path("b")))
    assert recorded[PLANT]["executor"] == recorded[THERMAL]["executor"] == RECORDED_EXECUTOR
    assert RECORDED_EXECUTOR == "single_threaded"
    # a graph's own choice wins
    chosen = by_name(GraphConfig(scenario="dm_exposure", bag=Path("b"),
                                 plant={"executor": "events"}, thermal={"executor": "events"}))
    assert chosen[PLANT]["executor"] == chosen[THERMAL]["executor"] == "events"


def _queue_depth(config: GraphConfig) -> int:
    arguments = build_graph(config).before[0].arguments
    return int(arguments[arguments.index("--queue-depth") + 1])


def test_the_recorder_queue_holds_a_lagging_backlog_within_a_memory_bound() -> None:
    # a small closed loop: as deep as a test stand's (the plant can outrun the recorder)
    small = GraphConfig(scenario="dm_exposure", bag=Path("b"), plant={"rows": 3, "cols": 3})
    assert _queue_depth(small) == TEST_STAND_QUEUE_DEPTH
    # a large grid: bounded by memory, still deeper than the topics' own depth
    large = GraphConfig(scenario="dm_exposure", bag=Path("b"), plant={"rows": 64, "cols": 64})
    assert _queue_depth(large) == closed_loop_queue_depth(64, 64)
    assert topics.DM_DEPTH < closed_loop_queue_depth(64, 64) < TEST_STAND_QUEUE_DEPTH
    assert closed_loop_queue_depth(64, 64) * 8 * 64 * 64 <= 1 << 30
    assert closed_loop_queue_depth(2000, 2000) == topics.DM_DEPTH
    stand = GraphConfig(scenario="characterisation", bag=Path("b"), with_controllers=False)
    assert _queue_depth(stand) == TEST_STAND_QUEUE_DEPTH


def test_a_test_stand_is_plant_and_recorder_only() -> None:
    graph = build_graph(GraphConfig(scenario="characterisation", bag=Path("b"),
                                    with_controllers=False))  # fmt: skip
    assert [n.name for n in graph.nodes] == [RECORDER, PLANT]
    assert graph.plant.parameters["wait_ready"] == [RECORDER]
    assert topics.SETPOINT not in graph.before[0].arguments


def test_a_parameters_file_for_the_scenario_grid_is_passed(tmp_path: Path) -> None:
    path = tmp_path / "ff.yaml"
    write_params_file(path, FeedforwardConfig(shape=(1, 1)))
    graph = build_graph(GraphConfig(scenario="thesis_ac", feedforward_params=path))
    feedforward = next(n for n in graph.nodes if n.name == FEEDFORWARD)
    assert feedforward.params_files == (path,)


def test_a_parameters_file_for_another_grid_is_refused_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "ff.yaml"
    write_params_file(path, FeedforwardConfig(shape=(12, 12)))
    with pytest.raises(GraphError) as err:
        build_graph(GraphConfig(scenario="thesis_ac", feedforward_params=path))
    assert "12 x 12 grid, the scenario's is 1 x 1" in str(err.value)
    assert "\n" not in str(err.value)
    path.write_text("not: [a parameters file")
    with pytest.raises(GraphError, match="feedforward parameters"):
        build_graph(GraphConfig(scenario="thesis_ac", feedforward_params=path))


def test_a_namespace_remaps_every_contract_topic_and_moves_the_parameters(
    tmp_path: Path,
) -> None:
    path = tmp_path / "ff.yaml"
    path.write_text("feedforward:\n  ros__parameters:\n    rows: 1\n    cols: 1\n"
                    "    law.m1: [-4e-17]\n")  # fmt: skip
    config = GraphConfig(scenario="thesis_ac", namespace="run0", feedforward_params=path,
                         log_dir=tmp_path / "logs")  # fmt: skip
    remaps = dict(topic_remaps("run0"))
    assert remaps[topics.COMMAND] == "/run0/dm/command"
    assert remaps[topics.DIAGNOSTICS] == "/run0/diagnostics"
    assert set(remaps) == set(topics.TOPIC_TYPES)
    feedforward = next(n for n in build_graph(config).nodes if n.name == FEEDFORWARD)
    copy = yaml.safe_load(feedforward.params_files[0].read_text())
    assert list(copy) == ["/run0/feedforward"]
    assert isinstance(copy["/run0/feedforward"]["ros__parameters"]["law.m1"][0], float)


def test_bringup_runs_exactly_the_graph(tmp_path: Path) -> None:
    config = GraphConfig(scenario="thesis_ac", bag=tmp_path / "bag", duration=2.0)
    before, plant = node_specs(config)
    graph = build_graph(config)
    assert [p.name for p in [*before, plant]] == [n.name for n in graph.nodes]
    for process, node in zip([*before, plant], graph.nodes, strict=True):
        command = list(process.command)
        assert command[0].endswith(f"lib/{node.package}/{node.executable}")
        for name in node.parameters:
            assert any(arg.startswith(f"{name}:=") for arg in command), (node.name, name)
    assert plant.primary and before[0].stop_stage == 1


def test_the_launch_file_describes_every_argument_and_builds_the_graph() -> None:
    tree = ast.parse(LAUNCH_FILE.read_text())
    assignment = next(
        node for node in tree.body
        if isinstance(node, ast.AnnAssign) and ast.unparse(node.target) == "ARGUMENTS"
    )  # fmt: skip
    assert assignment.value is not None
    arguments = ast.literal_eval(assignment.value)
    names = [name for name, _, _ in arguments]
    assert {"scenario", "mode", "feedforward_params", "bag", "duration", "time_scale",
            "namespace"} <= set(names)  # fmt: skip
    assert all(len(text) > 20 for _, _, text in arguments)
    calls = {ast.unparse(n.func) for n in ast.walk(tree) if isinstance(n, ast.Call)}
    assert "build_graph" in calls


def test_bringup_refuses_a_mismatched_parameters_file_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "ff.yaml"
    write_params_file(path, FeedforwardConfig(shape=(2, 2)))
    launcher = Path(sys.prefix) / "lib" / "es_bringup" / "bringup"
    result = subprocess.run(
        [str(launcher), "--scenario", "thesis_ac", "--feedforward-params", str(path),
         "--log-dir", str(tmp_path / "logs")],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1
    assert "2 x 2 grid, the scenario's is 1 x 1" in result.stderr


def test_a_parameters_file_judged_unusable_is_refused_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "ff.yaml"
    write_params_file(path, FeedforwardConfig(shape=(1, 1)),
                      verdict=("unusable", ["law m1 -8e-18 outside the physical interval"]))
    with pytest.raises(GraphError) as err:
        build_graph(GraphConfig(scenario="thesis_ac", feedforward_params=path))
    assert "unusable" in str(err.value) and "law m1" in str(err.value)
    assert "\n" not in str(err.value)
    write_params_file(path, FeedforwardConfig(shape=(1, 1)), verdict=("provisional", ["x"]))
    build_graph(GraphConfig(scenario="thesis_ac", feedforward_params=path))  # taken, warned
