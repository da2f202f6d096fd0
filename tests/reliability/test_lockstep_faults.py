"""Faults in the closed loop in lockstep (sim time): nodes killed and restarted, /clock stopping.

The bring-up's processes (recorder, thermal, feedforward, plant on a short 3 x 3
``dm_exposure``) run with short plant timeouts; a watcher checks every /dm/command. Mid-run
the feedforward node is killed with SIGKILL and restarted (the plant holds the last valid
command meanwhile, then the command stream resumes), later the thermal node (the plant
continues past its sync timeout, the feedforward holds on a stale temperature, then both
recover). When the plant has finished, /clock stands still: the other nodes must live on and
still answer a set point. Every message the plant published must be in the bag.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from rclpy.parameter import Parameter
from support.ros import READY_TIMEOUT

from es_bringup.bringup import GraphConfig, node_specs
from es_msgs_py import topics
from es_msgs_py.arrays import grid_to_msg
from es_msgs_py.bag import read_bag

from .graph import PLANT_OUTPUTS, Proc, Watcher

if TYPE_CHECKING:
    from .conftest import FaultCases

pytestmark = pytest.mark.dds

SHAPE = (3, 3)
# Sim seconds at 100 Hz control, 10 Hz sensors. Long enough that the thermal node's restart
# (seconds of start-up and discovery on a loaded machine) ends well before the run does: the
# watcher notices sim time passing KILL_THERMAL_AT late when the plant runs at full speed,
# and every 10 Hz sample without the thermal node costs sync_timeout of wall time.
DURATION = 30.0
KILL_FEEDFORWARD_AT = 1.0
KILL_THERMAL_AT = 3.0


def _kill_and_restart(
    watcher: Watcher, procs: dict[str, Proc], name: str, at: float, resumed: Callable[[], bool]
) -> tuple[bool, bool, str]:
    """SIGKILL ``name`` once sim time passes ``at``, restart it; return (others ok, resumed)."""
    if not watcher.wait_for(lambda: watcher.clock >= at, READY_TIMEOUT):
        plant_log = procs["plant"].output()[-600:]
        stuck = f"sim time stuck at {watcher.clock:.2f} s before the kill"
        return False, False, f"{stuck}; plant log: {plant_log}"
    procs[name].kill()
    clock_at_kill = watcher.clock
    # the rest goes on without it: the plant steps on its timeouts
    advanced = watcher.wait_for(lambda: watcher.clock > clock_at_kill + 0.05, READY_TIMEOUT)
    procs[name] = Proc(name, procs[name].command)
    restarted = time.monotonic()
    came_back = watcher.wait_for(resumed, READY_TIMEOUT)
    detail = (f"killed at {clock_at_kill:.2f} s sim, now {watcher.clock:.2f} s; "
              f"{'resumed' if came_back else 'not resumed'} "
              f"{time.monotonic() - restarted:.1f} s wall after the restart")
    if not came_back:
        detail += (f"; {name} log: {procs[name].output()[-400:]}; "
                   f"plant log: {procs['plant'].output()[-400:]}")
    return advanced, came_back, detail


def test_nodes_killed_and_restarted_in_lockstep(tmp_path: Path, fault_cases: FaultCases) -> None:
    area = "closed loop in lockstep"
    bag = tmp_path / "bag"
    config = GraphConfig(
        scenario="dm_exposure",
        bag=bag,
        # start_subscribers 2: the recorder and the watcher must match before step 0.
        # sync_timeout 1: with the thermal node dead each 10 Hz sample costs that much wall
        # time, which leaves its restart (start-up, discovery; seconds on a loaded machine)
        # about 100 s before the end; command_timeout 0.1 at 100 Hz leaves the feedforward's
        # restart 20 s before the thermal node is killed.
        plant={"rows": 3, "cols": 3, "duration": DURATION, "command_timeout": 0.1,
               "sync_timeout": 1.0, "start_subscribers": 2},
    )
    before, plant_spec = node_specs(config)
    watcher = Watcher(SHAPE, plant_peer=True)
    procs = {spec.name: Proc(spec.name, spec.command) for spec in before}
    try:
        # the watcher's own publisher and subscription of a topic match each other and count
        watcher.wait_matched({
            topics.COMMAND: (1, 0),  # from the feedforward
            topics.TEMPERATURE: (2, 3),  # thermal, watcher; feedforward, recorder, watcher
            topics.DIAGNOSTICS: (3, 0),  # recorder, thermal, feedforward
            topics.SETPOINT: (1, 3),  # watcher; feedforward, recorder, watcher
            topics.TEMPERATURE_RAW: (1, 4),  # watcher; thermal, feedforward, recorder, watcher
        }, list(procs.values()))
        # the plant matches the rest itself before its first step (matched command and
        # temperature sources, start_subscribers subscriptions of each of its outputs)
        procs["plant"] = Proc("plant", plant_spec.command)
        # the plant's parameter service is discovered now, not later amid the restarts' traffic
        watcher.parameter_client("plant")

        # The feedforward killed mid-run: the plant holds, the commands resume after restart.
        counted = watcher.command_count
        advanced, resumed, detail = _kill_and_restart(
            watcher, procs, "feedforward", KILL_FEEDFORWARD_AT,
            lambda: watcher.clock > KILL_FEEDFORWARD_AT + 0.5 and _grows(counted, watcher))
        fault_cases.expect(area, "feedforward SIGKILLed: plant steps on (holds the command)",
                           advanced and procs["plant"].alive(), detail)
        fault_cases.expect(area, "feedforward restarted: command stream resumes", resumed,
                           detail)

        # mid-run (the plant surely alive: its service was matched at its start)
        (plant_set,) = watcher.set_parameters(
            "plant", [Parameter("command_timeout", value=100.0)])
        fault_cases.expect(area, "plant parameter set at run time (read-only): rejected",
                           not plant_set[0] and bool(plant_set[1]), repr(plant_set))

        # The thermal node killed mid-run: the plant continues, estimates resume on restart.
        temperatures_seen = watcher.temperatures
        advanced, resumed, detail = _kill_and_restart(
            watcher, procs, "thermal", KILL_THERMAL_AT,
            lambda: watcher.temperatures > temperatures_seen + 2 and watcher.clock > 0)
        fault_cases.expect(area, "thermal SIGKILLed: plant steps on past its sync timeout",
                           advanced and procs["plant"].alive(), detail)
        fault_cases.expect(area, "thermal restarted: estimates resume", resumed, detail)

        finished = watcher.wait_for(lambda: not procs["plant"].alive(), 180.0)
        plant_exit = procs["plant"].popen.returncode
        fault_cases.expect(area, "plant finishes the scenario (exit 0)",
                           finished and plant_exit == 0, f"exit {plant_exit}")

        # /clock stopped with the plant: the others live on and still answer a set point.
        watcher.wait_for(lambda: False, 1.5)  # the scenario: a while without /clock
        sent = watcher.command_count()
        watcher.publish(topics.SETPOINT, grid_to_msg(np.full(SHAPE, 50e-9)))
        answered = watcher.wait_for(lambda: watcher.command_count() > sent, READY_TIMEOUT)
        alive = [n for n in ("thermal", "feedforward", "record") if procs[n].alive()]
        fault_cases.expect(area, "/clock stopped: nodes alive and answering",
                           answered and len(alive) == 3, f"alive: {alive}")
        for name in ("feedforward", "thermal"):
            code = procs[name].stop()
            fault_cases.expect(area, f"{name} exits cleanly after the faults", code == 0,
                               f"exit {code}: {procs[name].output()[-300:]}")
            if code != 0:
                fault_cases.crashed()
        procs["record"].stop()

        # the plant logs its published counts at exit; the bag must hold every message
        counts = read_bag(bag, PLANT_OUTPUTS)
        for topic in PLANT_OUTPUTS:
            published = procs["plant"].published(topic)
            recorded = len(counts[topic]) - watcher.injected.get(topic, 0)
            lost = (published or 0) - recorded
            fault_cases.lost(max(lost, 0))
            fault_cases.expect(area, f"{topic}: published == recorded",
                               published is not None and lost == 0,
                               f"published {published}, recorded {recorded}")
    finally:
        watcher.close()
        for proc in procs.values():
            proc.stop()
    with watcher.lock:
        check = watcher.commands
    fault_cases.commands(check.received, check.non_finite, check.out_of_limit)
    fault_cases.expect(area, "every /dm/command finite, in limits, contract layout",
                       check.non_finite == check.out_of_limit == check.bad_layout == 0,
                       "; ".join(check.problems[:5]))
    fault_cases.expect(area, "every /dm/temperature finite and within -50..200 degC",
                       watcher.estimator_non_finite_temperatures() == 0
                       and watcher.estimator_implausible_temperatures() == 0)
    fault_cases.assert_held()


def _grows(count: Callable[[], int], watcher: Watcher, window: float = 1.0) -> bool:
    """Whether commands keep arriving: the count rises within ``window`` wall seconds."""
    start = count()
    return watcher.wait_for(lambda: count() > start + 2, window)
