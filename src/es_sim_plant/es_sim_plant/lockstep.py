"""The plant node's stepping protocol, without ROS: lockstep, real time, hold-last, counts.

Per control step k (docs/architecture.md "Lockstep (sim time) protocol"): publish the state
(/clock, /dm/displacement, and when a sensor sample is due /dm/heat_load and
/dm/temperature/raw); with ``sync_temperature`` wait for one /dm/temperature (``sync_timeout``
wall s, then continue with a WARN); publish /dm/setpoint; wait for one /dm/command
(``command_timeout`` wall s, then hold the last valid command with a WARN); step. The first
step waits up to ``start_timeout`` for the peers and the nodes in ``wait_ready``. A topic
that nothing publishes is not waited for (WARN). A test stand (scenario with an excitation)
plays its own voltage program instead of waiting for commands.

Flow control: nothing else holds a plant back to its slowest reader (a test stand waits for
no controller, a recorder for nothing), and a reliable writer keeps only the contract's
newest ``DM_DEPTH`` samples, so a reader that falls further behind has lost the rest for good.
Every :data:`DELIVERY_WINDOW` steps the plant therefore waits (``delivery_timeout`` wall s)
until every reader has acknowledged what it published; a reader that does not (a stopped or
dead process) is counted and warned of, and until one wait succeeds again the plant only
checks briefly (:data:`LAGGING_SHARE` of the timeout), so a dead peer costs one timeout.

:class:`Lockstep` holds the protocol's state and counts; the node feeds it events
(:meth:`Lockstep.command`, :meth:`Lockstep.reject`, :meth:`Lockstep.temperature`,
:meth:`Lockstep.watchdog`, :meth:`Lockstep.realtime_tick`, :meth:`Lockstep.resume`) and
does the I/O it asks for through :class:`LockstepIo`. Wall time comes from an injected clock,
so tests drive the timeouts with a fake one.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from enum import Enum, auto
from typing import Protocol

import numpy as np

from es_common.arrays import FloatArray
from es_msgs_py.diagnostics import Level
from es_sim_plant.node_config import DELIVERY_WINDOW, LockstepSettings
from es_sim_plant.plant import Plant

__all__ = [
    "BATCH_WALL",
    "DELIVERY_WINDOW",
    "GRAPH_PERIOD",
    "LAGGING_SHARE",
    "Lockstep",
    "LockstepIo",
    "Phase",
    "StatusRow",
]

#: Longest stretch [s wall] the plant steps without returning to the executor.
BATCH_WALL = 0.02
#: Share of ``delivery_timeout`` the plant waits while a reader is known to lag.
LAGGING_SHARE = 0.05
#: How often the watchdog refreshes who publishes commands and temperatures [s wall].
GRAPH_PERIOD = 0.2
#: One diagnostic aspect: (aspect, level, message, key/values).
StatusRow = tuple[str, Level, str, dict[str, object]]


class Phase(Enum):
    """Where the lockstep protocol stands within the current step."""

    STARTING = auto()
    BEGIN = auto()
    WAIT_TEMPERATURE = auto()
    SETPOINT = auto()
    WAIT_COMMAND = auto()
    DONE = auto()


class LockstepIo(Protocol):
    """What the protocol asks of the node around it (publishing, the graph, logging)."""

    def publish_state(self) -> bool:
        """Publish /clock, /dm/displacement and a due sensor sample; return if one was due."""

    def publish_setpoint(self) -> None:
        """Publish the plant's set point of the current step."""

    def publish_command(self, command: FloatArray) -> None:
        """Publish the test stand's own command (V, grid) on /dm/command."""

    def peers_ready(self) -> bool:
        """Return whether every endpoint the first step waits for has matched."""

    def sources(self) -> tuple[bool, bool]:
        """Return whether anything publishes (/dm/command, /dm/temperature)."""

    def warn(self, kind: str, text: str) -> None:
        """Log a warning; ``kind`` names its kind (a node may throttle per kind)."""

    def publish_diagnostics(self) -> None:
        """Publish /diagnostics now (built from :meth:`Lockstep.statuses`)."""

    def resume_later(self) -> None:
        """Call :meth:`Lockstep.resume` once the executor has served other callbacks."""

    def delivered(self, limit: float) -> bool:
        """Wait up to ``limit`` wall s until every reader acknowledged everything published."""

    def finished(self) -> None:
        """Wrap up the ended scenario: summary, final diagnostics and (maybe) exit."""


class Lockstep:
    """The state of the stepping protocol for one plant (see the module docstring)."""

    def __init__(
        self,
        plant: Plant,
        io: LockstepIo,
        settings: LockstepSettings,
        clock: Callable[[], float] = time.monotonic,
        cpu_clock: Callable[[], float] = time.process_time,
    ) -> None:
        """Start in :attr:`Phase.STARTING` with a zero command held.

        Args:
            plant: the simulated mirror; stepped with the held command.
            io: the node's side (publishing, graph queries, logging).
            settings: the node's lockstep settings.
            clock: monotonic wall clock [s]; a fake one in tests.
            cpu_clock: process CPU time [s], for the summary's cost per step.

        """
        self.plant = plant
        self.io = io
        self.settings = settings
        self.test_stand = plant.excitation is not None
        self._clock = clock
        self._cpu_clock = cpu_clock
        self.phase = Phase.STARTING
        #: The last valid command [V, grid]; applied until a valid one replaces it.
        self.held: FloatArray = np.zeros(plant.shape)
        self.counts = {
            "commands": 0,
            "rejected": 0,
            "command_timeouts": 0,
            "no_command_source": 0,
            "sync_timeouts": 0,
            "delivery_timeouts": 0,
        }
        self.last_reject = ""
        #: What each awaited node said last about its readiness.
        self.ready: dict[str, bool] = dict.fromkeys(settings.wait_ready, False)
        self._reported_counts = dict(self.counts)
        self._levels: dict[str, Level] = {}
        self._has_command_source = False
        self._has_temperature_source = False
        self._graph_checked = 0.0
        self._deadline = 0.0
        self._paced = False
        self._delivered_at = 0
        self._readers_lagging = False
        self._start_wall = clock()
        self._last_command_wall = self._start_wall
        self.run_wall_start = 0.0
        self._run_cpu_start = 0.0

    # --- inputs ---------------------------------------------------------------------------
    def command(self, command: FloatArray) -> None:
        """Take a received command [V, grid of the plant's shape]; continue if waiting for it."""
        reason = self.plant.check_command(command)
        if reason is None:
            self.held = command
            self.counts["commands"] += 1
            self._last_command_wall = self._clock()
            self._continue_if_waiting()
        else:
            self.reject(reason)

    def reject(self, reason: str) -> None:
        """Count a command that was not acceptable; the last valid one stays held."""
        self.counts["rejected"] += 1
        self._report_problem("commands")
        self.last_reject = reason
        self.io.warn("reject", f"command rejected, holding the last valid one: {reason}")
        self._continue_if_waiting()

    def _continue_if_waiting(self) -> None:
        if self.phase is Phase.WAIT_COMMAND:
            self._apply_and_continue()

    def readiness(self, said: dict[str, bool]) -> None:
        """Note what nodes said about their readiness (only awaited nodes count)."""
        for name, ready in said.items():
            if name in self.ready:
                self.ready[name] = ready

    def not_ready(self) -> list[str]:
        """Return the awaited nodes that have not said they are ready."""
        return [name for name, ready in self.ready.items() if not ready]

    def temperature(self) -> None:
        """Go on when the step waits for /dm/temperature: an estimate arrived."""
        if self.phase is Phase.WAIT_TEMPERATURE:
            self.phase = Phase.SETPOINT
            self.resume()

    # --- start and timeouts ---------------------------------------------------------------
    def _started(self, now: float) -> bool:
        """Begin the run once the peers are present and ready, or ``start_timeout`` passed."""
        if not (self.io.peers_ready() and not self.not_ready()):
            timeout = self.settings.start_timeout
            if now - self._start_wall < timeout:
                return False
            not_ready = self.not_ready()
            self.io.warn(
                "start",
                f"start: peers not all present after {timeout:g} s"
                + (f" (not ready: {', '.join(not_ready)})" if not_ready else "")
                + "; stepping anyway",
            )
        self.phase = Phase.BEGIN
        self.run_wall_start = now
        self._run_cpu_start = self._cpu_clock()
        return True

    def _refresh_graph(self, now: float) -> None:
        self._graph_checked = now
        self._has_command_source, self._has_temperature_source = self.io.sources()

    def watchdog(self) -> None:
        """Periodic (lockstep): start when ready, resume after pacing, enforce the timeouts."""
        now = self._clock()
        if now - self._graph_checked >= GRAPH_PERIOD:
            self._refresh_graph(now)
        if self.phase is Phase.STARTING:
            if self._started(now):
                self._refresh_graph(now)
                self.resume()
            return
        if self._paced:
            self._paced = False
            self.resume()
            return
        if self.phase is Phase.WAIT_TEMPERATURE and now > self._deadline:
            self.counts["sync_timeouts"] += 1
            self._report_problem("sync")
            self.io.warn(
                "sync", f"no /dm/temperature within {self.settings.sync_timeout:g} s: continuing"
            )
            self.phase = Phase.SETPOINT
            self.resume()
        elif self.phase is Phase.WAIT_COMMAND and now > self._deadline:
            self.counts["command_timeouts"] += 1
            self._report_problem("commands")
            self.io.warn(
                "command",
                f"no /dm/command within {self.settings.command_timeout:g} s: "
                "holding the last valid one",
            )
            self._apply_and_continue()

    # --- stepping -------------------------------------------------------------------------
    def _apply_and_continue(self) -> None:
        self.plant.step(self.held)
        self.phase = Phase.BEGIN
        self.resume()

    def resume(self) -> None:
        """Run the protocol until it must wait for a message, or for a short wall budget."""
        settings = self.settings
        budget_end = self._clock() + BATCH_WALL
        while True:
            if self.phase is Phase.BEGIN:
                if self.plant.done:
                    self.io.publish_state()
                    self._finish()
                    return
                if self._ahead_of_max_speed():
                    self._paced = True  # the watchdog resumes
                    return
                if self.plant.k - self._delivered_at >= DELIVERY_WINDOW:
                    self._wait_for_readers()
                due = self.io.publish_state()
                if due and settings.sync_temperature:
                    if self._has_temperature_source:
                        self.phase = Phase.WAIT_TEMPERATURE
                        self._deadline = self._clock() + settings.sync_timeout
                        return
                    self.counts["sync_timeouts"] += 1
                    self._report_problem("sync")
                self.phase = Phase.SETPOINT
            if self.phase is Phase.SETPOINT:
                if self.test_stand:
                    self._play_excitation()
                else:
                    if settings.publish_setpoints:
                        self.io.publish_setpoint()
                    if self._has_command_source:
                        self.phase = Phase.WAIT_COMMAND
                        self._deadline = self._clock() + settings.command_timeout
                        return
                    self.counts["no_command_source"] += 1
                    self._report_problem("commands")
                    self.plant.step(self.held)
                self.phase = Phase.BEGIN
            if self.phase is not Phase.BEGIN:
                return
            if self._clock() > budget_end:
                self.io.resume_later()  # continue after the executor served other callbacks
                return

    def _wait_for_readers(self) -> None:
        """Let every reader acknowledge the last window before the plant publishes more."""
        self._delivered_at = self.plant.k
        timeout = self.settings.delivery_timeout
        if timeout <= 0.0:
            return
        limit = timeout * LAGGING_SHARE if self._readers_lagging else timeout
        if self.io.delivered(limit):
            self._readers_lagging = False
            return
        self.counts["delivery_timeouts"] += 1
        self._report_problem("delivery")
        if not self._readers_lagging:
            self.io.warn(
                "delivery",
                f"a reader did not acknowledge the last {DELIVERY_WINDOW} steps within "
                f"{limit:g} s: stepping on (it may miss messages; its counts will say)",
            )
        self._readers_lagging = True

    def _ahead_of_max_speed(self) -> bool:
        if self.settings.max_speed <= 0.0:
            return False
        elapsed = self._clock() - self.run_wall_start
        return self.plant.time > elapsed * self.settings.max_speed

    def _play_excitation(self) -> None:
        command = self.plant.excitation_command()
        if command is None:
            return
        self.io.publish_command(command)
        self.held = command
        self.plant.step(command)

    def realtime_tick(self) -> None:
        """One period of the real-time mode: publish, apply the newest valid command, step."""
        if self.phase is Phase.STARTING and not self._started(self._clock()):
            return
        if self.phase is not Phase.BEGIN:
            return
        if self.plant.done:
            self.io.publish_state()
            self._finish()
            return
        self.io.publish_state()
        if self.test_stand:
            self._play_excitation()
            return
        if self.settings.publish_setpoints:
            self.io.publish_setpoint()
        if self._clock() - self._last_command_wall > self.settings.command_timeout:
            self.counts["command_timeouts"] += 1
            self._last_command_wall = self._clock()
        self.plant.step(self.held)

    def _finish(self) -> None:
        self.phase = Phase.DONE
        self.io.finished()

    # --- summary and diagnostics ----------------------------------------------------------
    def summary(self, name: str) -> str:
        """Return the end-of-run line: steps, sim and wall time, speed, CPU cost and counts."""
        plant = self.plant
        wall = max(self._clock() - self.run_wall_start, 1e-9)
        cpu_per_step = (self._cpu_clock() - self._run_cpu_start) / max(plant.k, 1)
        sim = plant.time
        counts = ", ".join(f"{k} {v}" for k, v in self.counts.items())
        return (
            f"scenario '{name}' finished: {plant.k} steps, {sim:g} s sim in "
            f"{wall:.2f} s wall ({sim / wall:.2f}x real time, {plant.k / wall:.0f} "
            f"steps/s, plant CPU {cpu_per_step * 1e3:.3f} ms/step); {counts}"
        )

    def statuses(self) -> list[StatusRow]:
        """Return the node's diagnostic aspects (commands, sync, scenario) since the last call.

        A count that grew since the previous call makes its aspect WARN.
        """
        c = self.counts
        new = {k: c[k] - self._reported_counts.get(k, 0) for k in c}
        self._reported_counts = dict(c)
        scenario = self.plant.scenario
        command_problems = new["rejected"] + new["command_timeouts"] + new["no_command_source"]
        rows: list[StatusRow] = [
            (
                "commands",
                Level.WARN if command_problems else Level.OK,
                (
                    f"last: {self.last_reject}" if new["rejected"] else
                    "timeouts: holding the last valid command" if new["command_timeouts"] else
                    "no /dm/command publisher: holding the last valid command"
                    if new["no_command_source"] else "commands arriving"
                ),
                {k: c[k] for k in ("commands", "rejected", "command_timeouts",
                                   "no_command_source")},
            ),
            (
                "sync",
                Level.WARN if new["sync_timeouts"] else Level.OK,
                "/dm/temperature timed out or absent" if new["sync_timeouts"] else "in step",
                {"sync_timeouts": c["sync_timeouts"], "lockstep": self.settings.lockstep},
            ),
            (
                "scenario",
                Level.OK,
                "finished" if self.phase is Phase.DONE else
                "waiting for peers" if self.phase is Phase.STARTING else "running",
                {
                    "scenario": scenario.name,
                    "step": self.plant.k,
                    "steps": self.plant.steps,
                    "sim_time_s": float(self.plant.time),
                    "effects": ",".join(scenario.effects.enabled_names()) or "none",
                },
            ),
            (
                "delivery",
                Level.WARN if new["delivery_timeouts"] else Level.OK,
                "a reader did not acknowledge in time: it may miss messages"
                if new["delivery_timeouts"] else "every reader keeping up",
                {"delivery_timeouts": c["delivery_timeouts"],
                 "delivery_timeout_s": self.settings.delivery_timeout},
            ),
        ]  # fmt: skip
        for aspect, level, _message, _kv in rows:
            self._levels[aspect] = level
        return rows

    def _report_problem(self, aspect: str) -> None:
        """Publish diagnostics at once when ``aspect`` turns from OK to WARN."""
        if self._levels.get(aspect, Level.OK) is Level.OK:
            self.io.publish_diagnostics()
