"""A recorder stalled over the end of a lockstep run still gets every message (issue 35).

The recorder is stopped (SIGSTOP) from 1 s of sim time until the plant has logged the end
of its scenario, then continued: meanwhile its shared-memory port overflows, and what did
not fit reaches it only when the reliable protocol repairs it, on a writer heartbeat. A
plant that left as soon as its run was over took those messages with it: the last seconds
of the run were missing from the bag (published 401, recorded 220), while the recorder's
sequence numbers showed no gap. The plant must wait for its readers before it exits.
"""

from __future__ import annotations

import os
import re
import signal
from pathlib import Path

import pytest
from support.ros import READY_TIMEOUT

from es_bringup.bringup import GraphConfig, node_specs
from es_bringup.invariants import recorder_counts_from_log
from es_msgs_py import topics
from es_msgs_py.bag import read_bag

from .graph import PLANT_OUTPUTS, Proc, Watcher

pytestmark = pytest.mark.dds

SHAPE = (3, 3)
#: Sim seconds: 400 control steps, of which the recorder misses 300 while it is stopped.
DURATION = 4.0
STALL_FROM = 1.0
#: What the plant logs once its last step is done (before it waits for its readers).
FINISHED = re.compile(r"scenario '\w+' finished:")


def test_recorder_stalled_over_the_end_of_the_run_records_everything(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    config = GraphConfig(
        scenario="dm_exposure",
        bag=bag,
        # the fault test's timeouts: the plant's exit waited command_timeout for its readers
        plant={"rows": SHAPE[0], "cols": SHAPE[1], "duration": DURATION,
               "command_timeout": 0.1, "sync_timeout": 1.0, "start_subscribers": 2},
    )
    before, plant_spec = node_specs(config)
    watcher = Watcher(SHAPE, plant_peer=True)
    procs = {spec.name: Proc(spec.name, spec.command) for spec in before}
    recorder = procs["record"]
    stalled = False
    try:
        watcher.wait_matched({topics.TEMPERATURE_RAW: (1, 4)}, list(procs.values()))
        procs["plant"] = Proc("plant", plant_spec.command)
        assert watcher.wait_for(lambda: watcher.clock >= STALL_FROM, READY_TIMEOUT), (
            procs["plant"].output()[-600:])
        os.kill(recorder.popen.pid, signal.SIGSTOP)
        stalled = True
        # the ordering that lost the tail: the run ends while the recorder cannot take anything
        assert watcher.wait_for(lambda: bool(FINISHED.search(procs["plant"].output())),
                                READY_TIMEOUT), procs["plant"].output()[-600:]
        os.kill(recorder.popen.pid, signal.SIGCONT)
        stalled = False
        assert watcher.wait_for(lambda: not procs["plant"].alive(), READY_TIMEOUT)
        assert procs["plant"].popen.returncode == 0, procs["plant"].output()[-600:]
        for name in ("feedforward", "thermal", "record"):
            assert procs[name].stop() == 0, procs[name].output()[-600:]
    finally:
        if stalled:
            os.kill(recorder.popen.pid, signal.SIGCONT)
        watcher.close()
        for proc in procs.values():
            proc.stop()
    # the recorder's closing lines name no hole either (it knows of one from the counts the
    # plant announced on /diagnostics, which sequence numbers cannot show at the end)
    closing = recorder_counts_from_log(recorder.output().splitlines())
    assert all(t in closing and not closing[t].not_received for t in PLANT_OUTPUTS), (
        recorder.output()[-1200:])
    counts = read_bag(bag, PLANT_OUTPUTS)
    held = {t: (procs["plant"].published(t), len(counts[t])) for t in PLANT_OUTPUTS}
    assert all(sent == got for sent, got in held.values()), (
        f"(published, recorded): {held}\nplant: {procs['plant'].output()[-800:]}\n"
        f"recorder: {recorder.output()[-1200:]}")
