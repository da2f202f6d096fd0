"""Closed-loop graph for ``ros2 launch``: the same graph as ``ros2 run es_bringup bringup``.

    ros2 launch es_bringup closed_loop.launch.py scenario:=thesis_ac \
        mode:=inverse_hyperbolic calibration:=/path/calibration bag:=/tmp/run1

Both take their nodes from :func:`es_bringup.graph.build_graph`: the recorder (every /dm
topic and /diagnostics, sim time) when ``bag`` is given, the thermal node and the
feedforward node with the grid, sensors, time scale and sensor lag of the scenario, and the
plant (lockstep, exits when its scenario ends), whose first step waits until the thermal and
feedforward nodes report on /diagnostics that they are ready. When the plant exits the
launch shuts down, which sends SIGINT to the others, so the recorder closes its bag. A
feedforward parameters file made for another grid than the scenario's is refused before
anything starts. ``--show-args`` lists the arguments.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from launch import LaunchContext, LaunchDescription
from launch.action import Action
from launch.actions import DeclareLaunchArgument, OpaqueFunction, RegisterEventHandler, Shutdown
from launch.event_handlers import OnProcessExit
from launch_ros.actions import Node

from es_bringup.calibration_files import CalibrationFiles
from es_bringup.graph import GraphConfig, build_graph, topic_remaps

#: Every argument: name, default, description.
ARGUMENTS: list[tuple[str, str, str]] = [
    (
        "scenario",
        "thesis_ac",
        "Scenario: a shipped name (thesis_ac, thesis_dc_ac, dm_exposure, characterisation) "
        "or the path of a scenario YAML; it sets the grid, sensors and thermal set-up of "
        "every node.",
    ),
    (
        "mode",
        "inverse_hyperbolic",
        "Feedforward mode: inverse_hyperbolic, inverse_quadratic, linearized_dmax, observer "
        "or uncompensated (meanings: ros2 param describe /feedforward mode).",
    ),
    (
        "feedforward_params",
        "",
        "ROS 2 parameters YAML for the feedforward node (e.g. the calibration tool's "
        "feedforward_params.yaml); its rows/cols must be the scenario's grid. Empty: defaults.",
    ),
    (
        "thermal_params",
        "",
        "ROS 2 parameters YAML for the thermal node (the calibration tool's "
        "thermal_params.yaml: sensor lags, offsets); with it the thermal node undoes the "
        "sensor lag and the feedforward's temperature lead is off. Empty: none.",
    ),
    (
        "calibration",
        "",
        "A calibration's output directory (calibrate -o DIR): both parameters files are "
        "taken from it (instead of feedforward_params / thermal_params). Empty: none.",
    ),
    ("bag", "", "Bag directory to create (must not exist); empty: no recorder."),
    ("storage", "mcap", "Bag storage: mcap or sqlite3."),
    ("duration", "0", "Run length in simulation seconds; 0: the scenario's."),
    (
        "time_scale",
        "0",
        "Multiplier of the scenario's slow (thermal) times, 1 = physical length; 0: the "
        "scenario's own (the shipped ones are shortened).",
    ),
    (
        "namespace",
        "",
        "Run the graph below /NAMESPACE (every topic remapped, the bag keeps the contract "
        "names), so several graphs can share a ROS domain; empty: none.",
    ),
    (
        "test_stand",
        "false",
        "true: plant and recorder only, for a scenario with its own voltage program "
        "(characterisation).",
    ),
]


def _nodes(context: LaunchContext) -> list[Action]:
    """Build the graph from the launch arguments (at launch time) into launch_ros nodes."""
    arg = context.launch_configurations

    def positive(name: str) -> float | None:
        value = float(arg[name])
        return value if value > 0 else None

    namespace = arg["namespace"].strip("/") or None

    def path(name: str) -> Path | None:
        return Path(arg[name]) if arg[name] else None

    # CalibrationFilesError: one line, launch exits non-zero
    files = CalibrationFiles.given(
        path("calibration"), path("feedforward_params"), path("thermal_params")
    )
    config = GraphConfig(
        scenario=arg["scenario"],
        mode=arg["mode"],
        bag=Path(arg["bag"]) if arg["bag"] else None,
        storage=arg["storage"],
        feedforward_params=files.feedforward,
        thermal_params=files.thermal,
        with_controllers=arg["test_stand"].lower() not in ("true", "1"),
        namespace=namespace,
        duration=positive("duration"),
        time_scale=positive("time_scale"),
        # where a namespaced copy of the parameters file goes
        log_dir=Path(tempfile.gettempdir()) / f"es_dm_launch_{os.getpid()}",
    )
    graph = build_graph(config)  # GraphError: one line, launch exits non-zero
    remaps = topic_remaps(namespace)
    actions: list[Action] = []
    plant: Node | None = None
    for spec in graph.nodes:
        node = Node(
            package=spec.package,
            executable=spec.executable,
            name=spec.name,
            namespace=f"/{namespace}" if namespace else "",
            arguments=list(spec.arguments),
            parameters=[*(str(p) for p in spec.params_files), spec.parameters],
            remappings=remaps,
            output="screen",
            # nodes end on SIGINT; give a DDS teardown its own bounded time (node_main)
            sigterm_timeout="10",
        )
        actions.append(node)
        if spec is graph.plant:
            plant = node
    assert plant is not None
    actions.append(
        RegisterEventHandler(
            OnProcessExit(
                target_action=plant, on_exit=[Shutdown(reason="plant finished its scenario")]
            )
        )
    )
    return actions


def generate_launch_description() -> LaunchDescription:
    """Return the closed-loop launch description (arguments, then the graph at launch time)."""
    return LaunchDescription(
        [
            *(
                DeclareLaunchArgument(name, default_value=default, description=text)
                for name, default, text in ARGUMENTS
            ),
            OpaqueFunction(function=_nodes),
        ]
    )
