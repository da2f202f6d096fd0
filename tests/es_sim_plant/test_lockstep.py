"""The plant's stepping protocol without DDS: a fake clock and injected events.

Timeouts, hold-last-command, early/duplicate/rejected commands, a late temperature, the
start gate, pacing, the test stand and the real-time mode, each driven event by event.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pytest

from es_msgs_py.diagnostics import Level
from es_sim_plant.lockstep import BATCH_WALL, DELIVERY_WINDOW, LAGGING_SHARE, Lockstep, Phase
from es_sim_plant.node_config import LockstepSettings
from es_sim_plant.plant import Plant
from es_sim_plant.scenario import load_scenario

FloatArray = np.ndarray


class FakeClock:
    """A wall clock that moves only when told to, or by ``tick`` per reading."""

    def __init__(self, tick: float = 0.0) -> None:
        self.now = 100.0
        self.tick = tick

    def __call__(self) -> float:
        self.now += self.tick
        return self.now


@dataclass
class FakeIo:
    """Records what the protocol asks for; the graph is whatever the test sets."""

    plant: Plant
    peers: bool = True
    command_source: bool = True
    temperature_source: bool = True
    events: list[str] = field(default_factory=list)
    warnings: list[tuple[str, str]] = field(default_factory=list)
    commands: list[FloatArray] = field(default_factory=list)
    diagnostics: int = 0
    resumes: int = 0
    finishes: int = 0
    #: What each wait for the readers' acknowledgements answers, in turn (then: delivered).
    acknowledged: list[bool] = field(default_factory=list)
    #: (step, limit) of each wait for the readers.
    deliveries: list[tuple[int, float]] = field(default_factory=list)

    def publish_state(self) -> bool:
        due = not self.plant.done and self.plant.sensor_due()
        self.events.append(f"state {self.plant.k}" + (" sample" if due else ""))
        return due

    def publish_setpoint(self) -> None:
        self.events.append(f"setpoint {self.plant.k}")

    def publish_command(self, command: FloatArray) -> None:
        self.commands.append(command)

    def peers_ready(self) -> bool:
        return self.peers

    def sources(self) -> tuple[bool, bool]:
        return self.command_source, self.temperature_source

    def warn(self, kind: str, text: str) -> None:
        self.warnings.append((kind, text))

    def publish_diagnostics(self) -> None:
        self.diagnostics += 1

    def resume_later(self) -> None:
        self.resumes += 1

    def delivered(self, limit: float) -> bool:
        self.deliveries.append((self.plant.k, limit))
        return self.acknowledged.pop(0) if self.acknowledged else True

    def finished(self) -> None:
        self.finishes += 1


def make(
    scenario: str = "thesis_ac",
    duration: float = 0.1,
    clock: FakeClock | None = None,
    **settings: Any,
) -> tuple[Lockstep, FakeIo, FakeClock]:
    """Return a protocol on a 2 x 2 plant (thesis_ac: a sensor sample every 2nd step)."""
    plant = Plant(load_scenario(scenario).with_overrides(rows=2, cols=2, duration=duration))
    io = FakeIo(plant)
    clock = clock or FakeClock()
    core = Lockstep(
        plant, io, replace(LockstepSettings(), **settings), clock=clock, cpu_clock=lambda: 0.0
    )
    return core, io, clock


def phase(core: Lockstep) -> Phase:
    """Return where the protocol stands (a call: mypy does not keep the last narrowing)."""
    return core.phase


def started(core: Lockstep) -> None:
    """Let the watchdog start the run (peers present)."""
    core.watchdog()
    assert phase(core) is not Phase.STARTING


def test_a_step_waits_for_the_temperature_then_the_command_then_steps() -> None:
    core, io, _ = make()
    started(core)
    assert phase(core) is Phase.WAIT_TEMPERATURE and io.events == ["state 0 sample"]
    core.temperature()
    assert phase(core) is Phase.WAIT_COMMAND and io.events[-1] == "setpoint 0"
    command = np.full((2, 2), 10.0)
    core.command(command)
    assert core.plant.k == 1 and core.counts["commands"] == 1
    np.testing.assert_array_equal(core.held, command)
    # step 1 has no sensor sample: straight to the set point and the next command
    assert io.events[-2:] == ["state 1", "setpoint 1"] and phase(core) is Phase.WAIT_COMMAND


def test_the_start_waits_for_the_peers_until_start_timeout_then_steps_with_a_warning() -> None:
    core, io, clock = make(start_timeout=5.0)
    io.peers = False
    core.watchdog()
    assert phase(core) is Phase.STARTING and not io.events
    clock.now += 5.1
    core.watchdog()
    assert phase(core) is Phase.WAIT_TEMPERATURE
    assert [kind for kind, _ in io.warnings] == ["start"]
    assert "peers not all present after 5 s" in io.warnings[0][1]


def test_the_start_waits_for_every_node_in_wait_ready() -> None:
    core, io, _ = make(wait_ready=("thermal", "feedforward"), start_timeout=5.0)
    core.readiness({"thermal": True, "stranger": True})
    core.watchdog()
    assert phase(core) is Phase.STARTING and core.not_ready() == ["feedforward"]
    core.readiness({"feedforward": True})
    core.watchdog()
    assert phase(core) is Phase.WAIT_TEMPERATURE and not io.warnings
    # a start that times out names who was not ready
    late, late_io, late_clock = make(wait_ready=("thermal",), start_timeout=1.0)
    late_clock.now += 2.0
    late.watchdog()
    assert "(not ready: thermal)" in late_io.warnings[0][1]


def test_a_command_timeout_holds_the_last_valid_command() -> None:
    core, io, clock = make(command_timeout=0.5)
    started(core)
    core.temperature()
    first = np.full((2, 2), 20.0)
    core.command(first)  # step 0 -> 1
    assert phase(core) is Phase.WAIT_COMMAND
    clock.now += 0.4
    core.watchdog()
    assert core.plant.k == 1  # not yet
    clock.now += 0.2
    core.watchdog()
    assert core.plant.k == 2 and core.counts["command_timeouts"] == 1
    np.testing.assert_array_equal(core.held, first)
    assert io.warnings[-1][0] == "command" and "0.5 s" in io.warnings[-1][1]


def test_a_sync_timeout_continues_and_a_late_temperature_changes_nothing() -> None:
    core, io, clock = make(sync_timeout=0.3)
    started(core)
    clock.now += 0.31
    core.watchdog()
    assert core.counts["sync_timeouts"] == 1 and phase(core) is Phase.WAIT_COMMAND
    assert io.warnings[-1][0] == "sync"
    k = core.plant.k
    core.temperature()  # the late estimate: the protocol waits for the command now
    assert phase(core) is Phase.WAIT_COMMAND and core.plant.k == k


def test_an_early_command_is_held_but_steps_nothing_until_its_turn() -> None:
    core, _, _ = make()
    started(core)
    early = np.full((2, 2), 5.0)
    core.command(early)  # while the step waits for the temperature
    assert phase(core) is Phase.WAIT_TEMPERATURE and core.plant.k == 0
    np.testing.assert_array_equal(core.held, early)
    core.temperature()
    assert phase(core) is Phase.WAIT_COMMAND and core.plant.k == 0


def test_a_duplicate_command_is_taken_as_the_next_steps_command() -> None:
    core, _, _ = make()
    started(core)
    core.temperature()
    command = np.full((2, 2), 7.0)
    core.command(command)
    core.command(command)  # step 1 has no sample: the duplicate is step 1's command
    assert core.plant.k == 2 and core.counts["commands"] == 2
    assert phase(core) is Phase.WAIT_TEMPERATURE  # step 2 samples


@pytest.mark.parametrize("bad", [np.nan, 1e6])
def test_a_rejected_command_steps_with_the_last_valid_one_and_warns_once(bad: float) -> None:
    core, io, _ = make()
    started(core)
    core.temperature()
    valid = np.full((2, 2), 3.0)
    core.command(valid)  # k = 1, waiting for step 1's command
    before = io.diagnostics
    core.command(np.full((2, 2), bad))
    assert core.counts["rejected"] == 1 and core.plant.k == 2
    np.testing.assert_array_equal(core.held, valid)
    assert io.diagnostics == before + 1  # OK -> WARN published at once
    commands = core.statuses()[0]
    assert commands[0] == "commands" and commands[1] is Level.WARN
    assert commands[2].startswith("last: ")
    assert core.statuses()[0][1] is Level.OK  # nothing new since
    core.reject("wrong layout")
    kind, text = io.warnings[-1]
    assert kind == "reject" and text.endswith("holding the last valid one: wrong layout")


def test_without_a_command_or_temperature_source_nothing_is_waited_for() -> None:
    core, io, _ = make(duration=0.05)
    io.command_source = io.temperature_source = False
    started(core)
    assert phase(core) is Phase.DONE and io.finishes == 1
    assert core.plant.k == core.plant.steps == 5
    assert core.counts["no_command_source"] == 5 and core.counts["sync_timeouts"] == 3
    assert io.events[-1] == "state 5"  # the final displacement
    assert "finished: 5 steps" in core.summary("thesis_ac")
    assert core.statuses()[2][2] == "finished"


def test_without_sync_temperature_the_step_goes_straight_to_the_command() -> None:
    core, _, _ = make(sync_temperature=False)
    started(core)
    assert phase(core) is Phase.WAIT_COMMAND and core.plant.k == 0


def test_a_long_batch_yields_to_the_executor_and_resumes() -> None:
    core, io, _ = make(duration=0.05, clock=FakeClock(tick=BATCH_WALL / 2))
    io.command_source = io.temperature_source = False
    started(core)
    assert io.resumes == 1 and phase(core) is Phase.BEGIN and 0 < core.plant.k < 5
    while phase(core) is not Phase.DONE:
        core.resume()
    assert core.plant.k == 5 and io.finishes == 1


def test_max_speed_paces_the_steps_and_the_watchdog_resumes() -> None:
    core, io, clock = make(max_speed=1.0, sync_temperature=False)
    io.command_source = False
    started(core)
    assert core.plant.k == 1  # t = 0.01 s sim after 0 s wall: ahead
    core.watchdog()
    assert core.plant.k == 1  # resumed, still ahead
    clock.now += 0.015
    core.watchdog()
    core.watchdog()
    assert core.plant.k == 2


def test_a_test_stand_plays_its_program_without_waiting_for_commands() -> None:
    core, io, _ = make("characterisation", duration=0.02, sync_temperature=False)
    assert core.test_stand
    started(core)
    assert phase(core) is Phase.DONE and core.plant.k == 5
    assert len(io.commands) == 5 and "setpoint 0" not in io.events
    np.testing.assert_array_equal(core.held, io.commands[-1])


def test_real_time_steps_each_tick_and_counts_command_timeouts() -> None:
    core, io, clock = make(lockstep=False, command_timeout=0.5, duration=0.03)
    core.realtime_tick()  # starts (peers present) and steps
    assert core.plant.k == 1 and io.events[:2] == ["state 0 sample", "setpoint 0"]
    core.command(np.full((2, 2), 4.0))
    clock.now += 0.6
    core.realtime_tick()
    assert core.counts["command_timeouts"] == 1 and core.plant.k == 2
    core.realtime_tick()
    core.realtime_tick()
    assert phase(core) is Phase.DONE and io.finishes == 1 and core.plant.k == 3


def _test_stand_over(windows: int, **settings: Any) -> tuple[Lockstep, FakeIo]:
    """Return a test stand (no controller to pace it) of ``windows`` delivery windows + 1 step."""
    rate = load_scenario("characterisation").control_rate
    duration = (windows * DELIVERY_WINDOW + 1) / rate
    core, io, _ = make("characterisation", duration, sync_temperature=False, **settings)
    return core, io


def test_a_free_running_plant_waits_for_its_readers_every_window() -> None:
    core, io = _test_stand_over(3, delivery_timeout=2.0)
    started(core)
    while phase(core) is not Phase.DONE:
        core.resume()
    assert io.deliveries == [(k * DELIVERY_WINDOW, 2.0) for k in (1, 2, 3)]
    assert core.counts["delivery_timeouts"] == 0 and not io.warnings


def test_a_reader_that_does_not_acknowledge_is_counted_warned_of_once_and_waited_less() -> None:
    core, io = _test_stand_over(4, delivery_timeout=2.0)
    io.acknowledged = [False, False, True, True]
    started(core)
    while phase(core) is not Phase.DONE:
        core.resume()
    short = 2.0 * LAGGING_SHARE
    # one full wait, brief checks while the reader lags, the full wait once it caught up
    assert [limit for _, limit in io.deliveries] == [2.0, short, short, 2.0]
    assert core.counts["delivery_timeouts"] == 2
    assert [kind for kind, _ in io.warnings] == ["delivery"]
    assert "did not acknowledge the last 250 steps within 2 s" in io.warnings[0][1]
    (delivery,) = [row for row in core.statuses() if row[0] == "delivery"]
    assert delivery[1] is Level.WARN and delivery[3]["delivery_timeouts"] == 2
    assert "delivery_timeouts 2" in core.summary("stand")


def test_a_delivery_timeout_of_zero_never_waits() -> None:
    core, io = _test_stand_over(2, delivery_timeout=0.0)
    started(core)
    while phase(core) is not Phase.DONE:
        core.resume()
    assert not io.deliveries and core.plant.k == 2 * DELIVERY_WINDOW + 1
