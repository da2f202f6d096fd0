"""The bring-up's process supervisor, with small stand-in processes (no ROS)."""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

from es_bringup.supervisor import EXIT_INTERRUPTED, ProcessSpec, StopTimeouts, Supervisor

# A stand-in node: prints, then waits; on SIGINT appends "<name> stopped" to a journal file
# (a "slow" one first notes "<name> interrupted" and takes 0.3 s to stop). Once its signal
# handler is in place it creates "<journal>.<name>.up"; an "exit<N>" one exits with N as soon
# as every peer named in its fourth argument is up (a signal before would find no handler).
NODE = r"""
import os, signal, sys, time
name, journal, behaviour, peers = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4]
def note(line):
    with open(journal, "a") as f:
        f.write(f"{name} {line}\n")
def on_int(*_):
    if behaviour == "ignore_sigint":
        return
    if behaviour == "slow":
        note("interrupted")
        time.sleep(0.3)
    note("stopped")
    sys.exit(0)
signal.signal(signal.SIGINT, on_int)
open(f"{journal}.{name}.up", "w").close()
print(f"{name} up", flush=True)
if behaviour.startswith("exit"):
    for peer in filter(None, peers.split(",")):
        while not os.path.exists(f"{journal}.{peer}.up"):
            time.sleep(0.01)
    sys.exit(int(behaviour[4:]))
while True:
    time.sleep(0.05)
"""

# PROMPT: escalation bounds for stand-ins that stop at once: generous, since on a loaded machine a
# Python process can take seconds to be scheduled and run its handler (a stop well within the
# bound costs nothing). STUBBORN: for a stand-in that ignores SIGINT, so that its escalation to
# SIGTERM comes after 1 s instead of 30.
PROMPT = StopTimeouts(after_sigint=30.0, after_sigterm=30.0)
STUBBORN = StopTimeouts(after_sigint=1.0, after_sigterm=30.0)


def spec(
    name: str,
    journal: Path,
    behaviour: str = "wait",
    primary: bool = False,
    peers: tuple[str, ...] = (),
) -> ProcessSpec:
    # the recorder stand-in is stopped in a later stage than the nodes it records
    stage = 1 if name == "recorder" else 0
    command = [sys.executable, "-c", NODE, name, str(journal), behaviour, ",".join(peers)]
    return ProcessSpec(name, command, primary, stop_stage=stage)


def test_primary_finishing_stops_the_others_recorder_last(tmp_path: Path) -> None:
    journal = tmp_path / "journal"
    messages: list[str] = []
    sup = Supervisor(tmp_path / "logs", timeouts=PROMPT, announce=messages.append)
    sup.start(spec("recorder", journal))
    sup.start(spec("thermal", journal))
    sup.start(spec("plant", journal, "exit0", primary=True, peers=("recorder", "thermal")))
    outcome = sup.run(wall_timeout=60)
    assert outcome.exit_code == 0, outcome.reason
    assert outcome.exit_codes == {"recorder": 0, "thermal": 0, "plant": 0}
    # the recorder started first is stopped last, after the node it records
    assert journal.read_text().splitlines() == ["thermal stopped", "recorder stopped"]
    assert (tmp_path / "logs" / "thermal.log").read_text() == "thermal up\n"
    assert any("plant finished" in m for m in messages)


def test_processes_are_stopped_one_at_a_time_last_started_first(tmp_path: Path) -> None:
    # one process's teardown must not overlap the next one's (see StopTimeouts.settle)
    journal = tmp_path / "journal"
    sup = Supervisor(tmp_path / "logs", timeouts=PROMPT, announce=lambda _m: None)
    sup.start(spec("recorder", journal, "slow"))
    sup.start(spec("thermal", journal, "slow"))
    sup.start(spec("feedforward", journal, "slow"))
    peers = ("recorder", "thermal", "feedforward")
    sup.start(spec("plant", journal, "exit0", primary=True, peers=peers))
    outcome = sup.run(wall_timeout=60)
    assert outcome.exit_code == 0, outcome.reason
    assert journal.read_text().splitlines() == [
        f"{name} {event}"
        for name in ("feedforward", "thermal", "recorder")
        for event in ("interrupted", "stopped")
    ]


def test_a_node_dying_stops_the_rest_with_a_clear_reason(tmp_path: Path) -> None:
    journal = tmp_path / "journal"
    messages: list[str] = []
    sup = Supervisor(tmp_path / "logs", timeouts=PROMPT, announce=messages.append)
    sup.start(spec("recorder", journal))
    sup.start(spec("thermal", journal, "exit3", peers=("recorder", "plant")))
    sup.start(spec("plant", journal, primary=True))
    outcome = sup.run(wall_timeout=60)
    assert outcome.exit_code == 1
    assert outcome.reason == "thermal exited unexpectedly with exit code 3"
    assert journal.read_text().splitlines() == ["plant stopped", "recorder stopped"]
    assert any("| thermal up" in m for m in messages)  # the dead node's last log lines


def test_a_failing_primary_is_a_failure(tmp_path: Path) -> None:
    sup = Supervisor(tmp_path / "logs", timeouts=PROMPT, announce=lambda _m: None)
    sup.start(spec("plant", tmp_path / "journal", "exit2", primary=True))
    outcome = sup.run(wall_timeout=60)
    assert (outcome.exit_code, outcome.reason) == (1, "plant failed with exit code 2")


def test_a_process_ignoring_sigint_is_escalated_and_reported(tmp_path: Path) -> None:
    sup = Supervisor(tmp_path / "logs", timeouts=STUBBORN, announce=lambda _m: None)
    sup.start(spec("stubborn", tmp_path / "journal", "ignore_sigint"))
    sup.start(spec("plant", tmp_path / "journal", "exit0", primary=True, peers=("stubborn",)))
    outcome = sup.run(wall_timeout=60)
    assert outcome.exit_code == 1
    assert "unclean stop of stubborn" in outcome.reason
    assert outcome.exit_codes["stubborn"] == -15  # SIGTERM ended it


def test_interrupt_and_wall_timeout_stop_everything(tmp_path: Path) -> None:
    journal = tmp_path / "journal"
    sup = Supervisor(tmp_path / "logs", timeouts=PROMPT, announce=lambda _m: None)
    sup.start(spec("thermal", journal))
    sup.start(spec("plant", journal, primary=True))

    def interrupt_when_up() -> None:
        up = [Path(f"{journal}.{name}.up") for name in ("thermal", "plant")]
        deadline = time.monotonic() + 60.0
        while not all(p.exists() for p in up) and time.monotonic() < deadline:
            time.sleep(0.01)
        sup.interrupt()

    threading.Thread(target=interrupt_when_up).start()
    assert sup.run(wall_timeout=120).exit_code == EXIT_INTERRUPTED
    assert sorted(journal.read_text().splitlines()) == ["plant stopped", "thermal stopped"]

    sup2 = Supervisor(tmp_path / "logs2", timeouts=PROMPT, announce=lambda _m: None)
    journal2 = tmp_path / "journal2"
    sup2.start(spec("plant", journal2, primary=True))
    deadline = time.monotonic() + 60.0
    while not Path(f"{journal2}.plant.up").exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    outcome = sup2.run(wall_timeout=0.5)
    assert outcome.exit_code == 1
    assert "wall-clock limit" in outcome.reason
