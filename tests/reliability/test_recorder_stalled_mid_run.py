"""A recorder stopped in the middle of a free-running test stand still gets every message.

Issue 35, the demo's characterisation: nothing paces a test stand's plant to its recorder.
While the recorder is stopped (SIGSTOP) its shared-memory port overflows, and what did not
fit reaches it only when the writer's heartbeat asks what it lacks. With Fast DDS's 3 s
heartbeat and a writer history of the contract's 1,000 samples, a plant that ran on for
more than a history's worth of steps had dropped the samples by then: a hole in the bag
(the recorder's "lost before reception"). The ordering is forced: the recorder stays stopped
until the plant has run 1,500 steps past the stop, or has stopped stepping because it waits
for its readers (its flow control); either way, then continued, it must have everything.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest
from support.ros import READY_TIMEOUT

from es_bringup.bringup import GraphConfig, node_specs
from es_bringup.invariants import recorder_counts_from_log
from es_msgs_py import topics
from es_msgs_py.bag import read_bag
from es_sim_plant.node_config import DELIVERY_WINDOW
from es_sim_plant.scenario import load_scenario

from .graph import Proc, Watcher

pytestmark = pytest.mark.dds

SHAPE = (2, 2)
RATE = load_scenario("characterisation").control_rate
#: Steps the plant may run past the stop before the recorder goes on: beyond a writer's
#: history (4 windows), so a plant that does not wait for its readers loses samples.
PAST_THE_STOP = 6 * DELIVERY_WINDOW
#: Sim seconds: the stop at 2 s, then room for the steps past it and a tail.
STALL_FROM = 2.0
DURATION = STALL_FROM + 2 * PAST_THE_STOP / RATE
#: Wall seconds without a new /clock that say the plant waits for its readers.
HELD_BACK = 0.5
RECORDED = (topics.COMMAND, topics.DISPLACEMENT, topics.TEMPERATURE_RAW, topics.HEAT_LOAD)


def _stalled_until_held_back_or_past(watcher: Watcher) -> str:
    """Poll /clock until the plant ran PAST_THE_STOP steps or stood still; say which."""
    stop = watcher.clock
    seen, since = stop, time.monotonic()
    deadline = since + READY_TIMEOUT
    while time.monotonic() < deadline:
        now = watcher.clock
        if now >= stop + PAST_THE_STOP / RATE:
            return f"ran on from {stop:g} s to {now:g} s sim"
        if now != seen:
            seen, since = now, time.monotonic()
        elif time.monotonic() - since >= HELD_BACK:
            return f"held back at {now:g} s sim (stopped at {stop:g} s)"
        time.sleep(0.01)
    return f"neither within {READY_TIMEOUT:g} s (clock {watcher.clock:g} s)"


def test_recorder_stopped_mid_run_of_a_free_running_test_stand_records_everything(
    tmp_path: Path,
) -> None:
    bag = tmp_path / "bag"
    config = GraphConfig(
        scenario="characterisation",
        bag=bag,
        with_controllers=False,
        plant={"rows": SHAPE[0], "cols": SHAPE[1], "duration": DURATION,
               "start_subscribers": 2},  # the recorder and the watcher
    )
    before, plant_spec = node_specs(config)
    watcher = Watcher(SHAPE, plant_peer=True)
    procs = {spec.name: Proc(spec.name, spec.command) for spec in before}
    recorder = procs["record"]
    stalled = False
    try:
        watcher.wait_matched({topics.TEMPERATURE_RAW: (1, 2)}, list(procs.values()))
        procs["plant"] = plant = Proc("plant", plant_spec.command)
        assert watcher.wait_for(lambda: watcher.clock >= STALL_FROM, READY_TIMEOUT), (
            plant.output()[-600:])
        os.kill(recorder.popen.pid, signal.SIGSTOP)
        stalled = True
        how = _stalled_until_held_back_or_past(watcher)
        os.kill(recorder.popen.pid, signal.SIGCONT)
        stalled = False
        assert watcher.wait_for(lambda: not plant.alive(), READY_TIMEOUT), how
        assert plant.popen.returncode == 0, plant.output()[-600:]
        assert recorder.stop() == 0, recorder.output()[-600:]
    finally:
        if stalled:
            os.kill(recorder.popen.pid, signal.SIGCONT)
        watcher.close()
        for proc in procs.values():
            proc.stop()
    closing = recorder_counts_from_log(recorder.output().splitlines())
    assert all(t in closing and not closing[t].not_received for t in RECORDED), (
        f"{how}\n{recorder.output()[-1200:]}")
    counts = read_bag(bag, RECORDED)
    held = {t: (plant.published(t), len(counts[t])) for t in RECORDED}
    assert all(sent == got for sent, got in held.values()), (
        f"{how}; (published, recorded): {held}\nplant: {plant.output()[-800:]}\n"
        f"recorder: {recorder.output()[-1200:]}")
