"""Closed-loop graph for a full ROS 2 install: the same graph as ``ros2 run es_sim_plant bringup``.

    ros2 launch es_sim_plant closed_loop.launch.py scenario:=thesis_ac rows:=1 cols:=1 \
        mode:=inverse_hyperbolic feedforward_params:=/path/calibrated.yaml bag:=/tmp/run1

Starts the recorder (every /dm topic and /diagnostics, sim time), the thermal node, the
feedforward node and the plant (lockstep, exits when its scenario ends); when the plant exits
the launch shuts down, which sends SIGINT to the others so the recorder closes its bag.
Unlike the bring-up, launch does not wait for the other nodes' subscriptions before starting
the plant (the plant's lockstep start-up waits for its peers and, with start_subscribers 1,
for the recorder), and it does not derive the thermal node's sensor (positions, noise, the
known lag ``sensor_lag_tau``), time-scale and thermal-network parameters from the scenario:
give the grid as rows/cols (the bring-up does all of that).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, RegisterEventHandler, Shutdown
from launch.conditions import IfCondition, UnlessCondition
from launch.event_handlers import OnProcessExit
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node

RECORDED_TOPICS = [
    "/dm/heat_load",
    "/dm/temperature/raw",
    "/dm/temperature",
    "/dm/setpoint",
    "/dm/command",
    "/dm/displacement",
    "/diagnostics",
]


def generate_launch_description() -> LaunchDescription:
    scenario = LaunchConfiguration("scenario")
    mode = LaunchConfiguration("mode")
    feedforward_params = LaunchConfiguration("feedforward_params")
    bag = LaunchConfiguration("bag")
    grid = {"rows": LaunchConfiguration("rows"), "cols": LaunchConfiguration("cols")}
    has_params = PythonExpression(["'", feedforward_params, "' != ''"])
    sim_time = {"use_sim_time": True}

    recorder = Node(
        package="es_msgs_py",
        executable="record",
        name="record",
        arguments=["-o", bag, *RECORDED_TOPICS],
        parameters=[sim_time],
        output="screen",
    )
    thermal = Node(
        package="es_thermal",
        executable="thermal_node",
        name="thermal",
        parameters=[{**sim_time, **grid}],
        output="screen",
    )
    feedforward_with_file = Node(
        package="es_feedforward",
        executable="feedforward_node",
        name="feedforward",
        parameters=[feedforward_params, {**sim_time, **grid, "mode": mode}],
        output="screen",
        condition=IfCondition(has_params),
    )
    feedforward_defaults = Node(
        package="es_feedforward",
        executable="feedforward_node",
        name="feedforward",
        parameters=[{**sim_time, **grid, "mode": mode}],
        output="screen",
        condition=UnlessCondition(has_params),
    )
    plant = Node(
        package="es_sim_plant",
        executable="plant_node",
        name="plant",
        parameters=[
            {
                "scenario": scenario,
                "lockstep": True,
                "exit_when_done": True,
                "start_subscribers": 1,
            }
        ],
        output="screen",
    )
    return LaunchDescription(
        [
            DeclareLaunchArgument("scenario", default_value="thesis_ac"),
            DeclareLaunchArgument("mode", default_value="inverse_hyperbolic"),
            DeclareLaunchArgument("feedforward_params", default_value=""),
            DeclareLaunchArgument("rows", default_value="12", description="grid rows"),
            DeclareLaunchArgument("cols", default_value="12", description="grid columns"),
            DeclareLaunchArgument("bag", description="bag directory to create"),
            recorder,
            thermal,
            feedforward_with_file,
            feedforward_defaults,
            plant,
            RegisterEventHandler(
                OnProcessExit(
                    target_action=plant,
                    on_exit=[Shutdown(reason="plant finished its scenario")],
                )
            ),
        ]
    )
