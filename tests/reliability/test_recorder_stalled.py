"""A recorder stopped (SIGSTOP) during a run still gets every message (issue 35).

While the recorder is stopped its shared-memory port overflows, and what did not fit reaches
it only when the reliable protocol repairs it, on a writer heartbeat. Two orderings lost
messages, each forced here:

- over the end of a lockstep run (stopped from 1 s of sim time until the plant has logged
  the end of its scenario): a plant that left as soon as its run was over took the repairs
  with it, the last seconds were missing from the bag (published 401, recorded 220) while
  the recorder's sequence numbers showed no gap. The plant must wait for its readers before
  it exits.
- in the middle of a free-running test stand (the demo's characterisation): nothing paced
  the plant to its recorder, and with Fast DDS's 3 s heartbeat and a writer history of the
  contract's 1,000 samples a plant that ran on for more than a history had dropped the
  samples before the repair (357 commands and 341 displacements "lost before reception").
  The recorder stays stopped until the plant has run 1,500 steps past the stop or has
  stopped stepping because it waits for its readers (its flow control).
"""

from __future__ import annotations

import os
import re
import signal
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest
from support.ros import READY_TIMEOUT

from es_bringup.bringup import GraphConfig, node_specs
from es_msgs_py import topics
from es_sim_plant.node_config import DELIVERY_WINDOW
from es_sim_plant.scenario import load_scenario

from .graph import PLANT_OUTPUTS, Proc, Watcher, assert_recorded_everything

pytestmark = pytest.mark.dds

#: What the plant logs once its last step is done (before it waits for its readers).
FINISHED = re.compile(r"scenario '\w+' finished:")
#: The test stand's control rate [Hz] and the steps its plant may run past the stop before
#: the recorder goes on: beyond a writer's history (4 windows), so a plant that does not
#: wait for its readers loses samples.
STAND_RATE = load_scenario("characterisation").control_rate
PAST_THE_STOP = 6 * DELIVERY_WINDOW
#: Wall seconds without a new /clock that say the plant waits for its readers.
HELD_BACK = 0.5


def _run_with_recorder_stopped(
    config: GraphConfig,
    shape: tuple[int, int],
    matched: int,
    stall_from: float,
    stall: Callable[[Watcher, Proc], str],
) -> tuple[Proc, Proc, str]:
    """Run ``config``'s graph, the recorder stopped from ``stall_from`` s sim while ``stall``.

    ``matched``: the subscriptions of /dm/temperature/raw the watcher's publisher needs
    before the plant starts (the graph's nodes up). ``stall`` returns how the stop ended.
    Returns the plant, the recorder (both ended cleanly) and that description.
    """
    before, plant_spec = node_specs(config)
    watcher = Watcher(shape, plant_peer=True)
    procs = {spec.name: Proc(spec.name, spec.command) for spec in before}
    recorder = procs["record"]
    stalled = False
    try:
        watcher.wait_matched({topics.TEMPERATURE_RAW: (1, matched)}, list(procs.values()))
        procs["plant"] = plant = Proc("plant", plant_spec.command)
        assert watcher.wait_for(lambda: watcher.clock >= stall_from, READY_TIMEOUT), (
            plant.output()[-600:])
        os.kill(recorder.popen.pid, signal.SIGSTOP)
        stalled = True
        how = stall(watcher, plant)
        os.kill(recorder.popen.pid, signal.SIGCONT)
        stalled = False
        assert watcher.wait_for(lambda: not plant.alive(), READY_TIMEOUT), how
        assert plant.popen.returncode == 0, plant.output()[-600:]
        for spec in before:
            assert procs[spec.name].stop() == 0, procs[spec.name].output()[-600:]
    finally:
        if stalled:
            os.kill(recorder.popen.pid, signal.SIGCONT)
        watcher.close()
        for proc in procs.values():
            proc.stop()
    return plant, recorder, how


def _until_finished(watcher: Watcher, plant: Proc) -> str:
    """The ordering that lost the tail: the run ends while the recorder cannot take anything."""
    assert watcher.wait_for(lambda: bool(FINISHED.search(plant.output())), READY_TIMEOUT), (
        plant.output()[-600:])
    return "stopped until the plant finished"


def _until_held_back_or_past(watcher: Watcher, _plant: Proc) -> str:
    """Poll /clock until the plant ran PAST_THE_STOP steps or stood still; say which."""
    stop = seen = watcher.clock
    since = time.monotonic()
    deadline = since + READY_TIMEOUT
    while time.monotonic() < deadline:
        now = watcher.clock
        if now >= stop + PAST_THE_STOP / STAND_RATE:
            return f"ran on from {stop:g} s to {now:g} s sim"
        if now != seen:
            seen, since = now, time.monotonic()
        elif time.monotonic() - since >= HELD_BACK:
            return f"held back at {now:g} s sim (stopped at {stop:g} s)"
        time.sleep(0.01)
    return f"neither within {READY_TIMEOUT:g} s (clock {watcher.clock:g} s)"


def test_recorder_stalled_over_the_end_of_the_run_records_everything(tmp_path: Path) -> None:
    shape = (3, 3)
    bag = tmp_path / "bag"
    config = GraphConfig(
        scenario="dm_exposure",
        bag=bag,
        # the fault test's timeouts: the plant's exit waited command_timeout for its readers;
        # 400 control steps, of which the recorder misses 300 while it is stopped
        plant={"rows": shape[0], "cols": shape[1], "duration": 4.0,
               "command_timeout": 0.1, "sync_timeout": 1.0, "start_subscribers": 2},
    )
    # the watcher's raw publisher: its own, the thermal node's, the feedforward's, the recorder's
    plant, recorder, how = _run_with_recorder_stopped(config, shape, 4, 1.0, _until_finished)
    assert_recorded_everything(bag, plant, recorder, PLANT_OUTPUTS, how)


def test_recorder_stopped_mid_run_of_a_free_running_test_stand_records_everything(
    tmp_path: Path,
) -> None:
    shape = (2, 2)
    stall_from = 2.0
    bag = tmp_path / "bag"
    config = GraphConfig(
        scenario="characterisation",
        bag=bag,
        with_controllers=False,
        plant={"rows": shape[0], "cols": shape[1],
               "duration": stall_from + 2 * PAST_THE_STOP / STAND_RATE,
               "start_subscribers": 2},  # the recorder and the watcher
    )
    recorded: Sequence[str] = (
        topics.COMMAND, topics.DISPLACEMENT, topics.TEMPERATURE_RAW, topics.HEAT_LOAD)
    # the watcher's raw publisher: its own subscription and the recorder's
    plant, recorder, how = _run_with_recorder_stopped(
        config, shape, 2, stall_from, _until_held_back_or_past)
    assert_recorded_everything(bag, plant, recorder, recorded, how)
