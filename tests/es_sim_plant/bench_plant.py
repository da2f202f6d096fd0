"""Benchmarks of the plant (not collected by pytest): core steps/s and plant-only lockstep rate.

Usage (from the repository root, after ./scripts/bootstrap)::

    ROS_DOMAIN_ID=212 ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST \
        .venv/bin/python tests/es_sim_plant/bench_plant.py [core|lockstep|all]

``core``: Plant.step on dm_exposure at 12 x 12 and 32 x 32 (no effects, then all effects).
``lockstep``: the installed plant_node process on dm_exposure (12 x 12, 100 Hz, no thermal
node: sync_temperature off) against an in-process echo node that answers every set point
with a command; prints steps/s and the real-time factor the plant reports.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import rclpy
from std_msgs.msg import Float64MultiArray

from es_msgs_py import topics
from es_msgs_py.arrays import grid_to_msg, msg_to_grid
from es_sim_plant.effects import EFFECT_NAMES
from es_sim_plant.plant import Plant
from es_sim_plant.scenario import load_scenario


def bench_core() -> None:
    """Print core steps/s for 12 x 12 and 32 x 32 grids."""
    for n in (12, 32):
        for effects in ({}, dict.fromkeys(EFFECT_NAMES, True)):
            scenario = load_scenario("dm_exposure").with_overrides(rows=n, cols=n, effects=effects)
            plant = Plant(scenario)
            command = np.full((n, n), 120.0)
            count = 2000
            start = time.perf_counter()
            for _ in range(count):
                plant.step(command)
            rate = count / (time.perf_counter() - start)
            label = "all effects" if effects else "no effects"
            print(f"core {n} x {n}, {label}: {rate:.0f} steps/s")


def bench_lockstep(duration: float = 10.0) -> None:
    """Run plant_node in lockstep against an echo command source and print its rate."""
    launcher = os.environ.get(
        "BENCH_PLANT", os.path.join(sys.prefix, "lib", "es_sim_plant", "plant_node")
    )
    args = [
        launcher, "--ros-args", "-p", "scenario:=dm_exposure", "-p", "sync_temperature:=false",
        "-p", f"duration:={duration}", "-p", "exit_when_done:=true",
    ]  # fmt: skip
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("bench_echo", context=context)
    publisher = node.create_publisher(Float64MultiArray, topics.COMMAND, topics.DM_QOS)
    answered = [0]

    def echo(msg: Float64MultiArray) -> None:
        setpoint = msg_to_grid(msg)
        publisher.publish(grid_to_msg(setpoint * 1.0e9))  # 100 nm -> 100 V
        answered[0] += 1

    node.create_subscription(Float64MultiArray, topics.SETPOINT, echo, topics.DM_QOS)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    process = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        while process.poll() is None:
            executor.spin_once(timeout_sec=0.05)
        output = process.stdout.read() if process.stdout else ""
    finally:
        if process.poll() is None:
            process.terminate()
            process.wait(10)
        node.destroy_node()
        rclpy.shutdown(context=context)
    summary = [line for line in output.splitlines() if "finished" in line]
    print(f"lockstep dm_exposure 12 x 12 at 100 Hz, {answered[0]} set points answered:")
    print("  " + (summary[0] if summary else output[-2000:]))


if __name__ == "__main__":
    which = sys.argv[1] if len(sys.argv) > 1 else "all"
    if which in ("core", "all"):
        bench_core()
    if which in ("lockstep", "all"):
        bench_lockstep()
