"""Start, watch and stop a group of processes: the process half of the bring-up.

A small stand-in for what ``ros2 launch`` does for a node graph (there is no launch on PyPI):
each process gets its own log file (optionally echoed with a ``[name]`` prefix), a process that
dies while it is still needed stops the group with a clear message, and the group ends when its
primary process (the plant, which ends its scenario) exits. Stopping is by PID only: SIGINT,
then SIGTERM, then SIGKILL after timeouts, one process at a time and in stages
(:attr:`ProcessSpec.stop_stage`), so that a recorder is stopped last and closes its bag after
everything it records has gone quiet.

No rclpy here: the supervisor knows commands and exit codes, nothing about ROS.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TextIO

from es_bringup.errors import SupervisorError

#: Exit code of :meth:`Supervisor.run` when a process failed or a stop was not clean.
EXIT_FAILURE = 1
#: Exit code of :meth:`Supervisor.run` when the group was interrupted (SIGINT/SIGTERM).
EXIT_INTERRUPTED = 130

_PR_SET_PDEATHSIG = 1


@dataclass(frozen=True)
class ProcessSpec:
    """One process of the group.

    Attributes:
        name: short unique name, used for the log file and the echo prefix.
        command: argv of the process.
        primary: its exit ends the run (exit 0 = success); at least one process is primary.
        clean_exit_codes: exit codes accepted when the supervisor stops the process
            (SIGINT-handling nodes exit 0; a process killed by a signal shows ``-signum``).
        stop_stage: processes are stopped stage by stage, lowest first, and within a stage
            the last started first; a recorder gets a later stage than the nodes it records.

    """

    name: str
    command: Sequence[str]
    primary: bool = False
    clean_exit_codes: frozenset[int] = field(default_factory=lambda: frozenset({0}))
    stop_stage: int = 0


@dataclass(frozen=True)
class StopTimeouts:
    """Seconds to wait after SIGINT and after SIGTERM before escalating, and before each stop.

    ``settle`` passes before each process is signalled, so that the previous one's departure
    has reached the others first: a ROS 2 node on Fast DDS 2.14 can hang for good in its
    participant teardown while it is handling another participant's goodbye.
    """

    after_sigint: float = 10.0
    after_sigterm: float = 5.0
    settle: float = 0.3


@dataclass
class Outcome:
    """How the group ended: exit code, a one-line reason and each process's exit code."""

    exit_code: int
    reason: str
    exit_codes: dict[str, int | None]


# Looked up once here: the child between fork and exec only calls it (no library loading).
_PRCTL = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None


def _die_with_parent() -> None:
    """Ask Linux to SIGTERM the child if the supervisor dies without stopping it."""
    if _PRCTL is not None:
        _PRCTL(_PR_SET_PDEATHSIG, int(signal.SIGTERM))


class _Running:
    """A started process with the thread copying its output to the log."""

    def __init__(
        self, spec: ProcessSpec, log_path: Path, echo: TextIO | None, env: dict[str, str] | None
    ) -> None:
        self.spec = spec
        self.log_path = log_path
        self._log: IO[str] = log_path.open("w", encoding="utf-8")
        # New session: a Ctrl-C in the terminal reaches the supervisor only, which then stops
        # the group in order instead of every process racing to exit at once.
        self.popen = subprocess.Popen(
            list(spec.command),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            preexec_fn=_die_with_parent,  # noqa: PLW1509 - only calls prctl, no locks
            env=env,
            text=True,
            errors="replace",
            bufsize=1,
        )
        self._pump = threading.Thread(
            target=self._copy_output, args=(echo,), name=f"log-{spec.name}", daemon=True
        )
        self._pump.start()

    def _copy_output(self, echo: TextIO | None) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            self._log.write(line)
            self._log.flush()
            if echo is not None:
                echo.write(f"[{self.spec.name}] {line}")
                echo.flush()

    def finish_log(self) -> None:
        """Wait for the output copy to drain (the process has exited) and close the log."""
        self._pump.join(timeout=5.0)
        self._log.close()

    def tail(self, lines: int = 8) -> str:
        """Return the last ``lines`` lines of the log."""
        text = self.log_path.read_text(encoding="utf-8", errors="replace")
        return "\n".join(text.splitlines()[-lines:])


class Supervisor:
    """Run a group of processes to completion and stop them cleanly (see module docstring).

    Args:
        log_dir: directory for ``<name>.log`` files (created).
        echo: stream to echo output to with a ``[name]`` prefix, or ``None``.
        timeouts: escalation timeouts when stopping.
        env: environment of the processes (``None``: inherit).
        announce: receives one-line progress messages of the supervisor itself.

    """

    def __init__(
        self,
        log_dir: Path,
        echo: TextIO | None = None,
        timeouts: StopTimeouts | None = None,
        env: dict[str, str] | None = None,
        announce: Callable[[str], None] | None = None,
    ) -> None:
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self._echo = echo
        self._timeouts = timeouts or StopTimeouts()
        self._env = env
        self._announce = announce or (lambda text: print(f"[bringup] {text}", file=sys.stderr))
        self._running: list[_Running] = []
        self._interrupted = threading.Event()

    def start(self, spec: ProcessSpec) -> None:
        """Start one process now."""
        if any(r.spec.name == spec.name for r in self._running):
            raise SupervisorError(f"process name {spec.name!r} used twice")
        running = _Running(spec, self.log_dir / f"{spec.name}.log", self._echo, self._env)
        self._running.append(running)
        self._announce(f"started {spec.name} (pid {running.popen.pid})")

    def announce(self, text: str) -> None:
        """Pass a one-line progress message on."""
        self._announce(text)

    def interrupt(self) -> None:
        """Ask :meth:`run` to stop the group (safe from a signal handler)."""
        self._interrupted.set()

    def check_alive(self) -> Outcome | None:
        """Return a failure outcome if a started process has already exited, else ``None``.

        Used while waiting for processes to become ready, before the primary starts.
        """
        for running in self._running:
            code = running.popen.poll()
            if code is not None:
                return self._fail(running, code)
        return None

    def run(
        self,
        wall_timeout: float | None = None,
        poll_s: float = 0.05,
        on_primary_done: Callable[[], None] | None = None,
    ) -> Outcome:
        """Watch the started processes until the primary exits, then stop the rest.

        ``on_primary_done`` runs after the primary exited 0, before the others are stopped
        (e.g. to let a recorder catch up).

        Returns:
            exit code 0 when the primary exited 0 and every other process stopped cleanly;
            1 when a process died unexpectedly, the primary failed, a stop needed SIGKILL or
            ``wall_timeout`` passed; 130 when interrupted (1 if a process then stopped uncleanly).

        """
        if not any(r.spec.primary for r in self._running):
            raise SupervisorError("no primary process started")
        deadline = None if wall_timeout is None else time.monotonic() + wall_timeout
        while True:
            if self._interrupted.is_set():
                unclean = self._stop_all()
                if unclean:
                    return self._outcome(
                        EXIT_FAILURE, f"interrupted; unclean stop of {', '.join(unclean)}"
                    )
                return self._outcome(EXIT_INTERRUPTED, "interrupted; stopped every process")
            for running in self._running:
                code = running.popen.poll()
                if code is None:
                    continue
                if running.spec.primary and code == 0:
                    if on_primary_done is not None:
                        running.finish_log()  # its whole output is in the log first
                        on_primary_done()
                    self._announce(f"{running.spec.name} finished; stopping the others")
                    return self._finish_after_primary(running)
                return self._fail(running, code)
            if deadline is not None and time.monotonic() > deadline:
                self._stop_all()
                return self._outcome(
                    EXIT_FAILURE, f"wall-clock limit of {wall_timeout:g} s reached; stopped"
                )
            time.sleep(poll_s)

    def stop(self) -> Outcome:
        """Stop every process now (used when start-up fails); returns the outcome."""
        self._stop_all()
        return self._outcome(EXIT_FAILURE, "stopped during start-up")

    def _finish_after_primary(self, primary: _Running) -> Outcome:
        unclean = self._stop_all()
        if unclean:
            return self._outcome(EXIT_FAILURE, f"unclean stop of {', '.join(unclean)}")
        return self._outcome(0, f"{primary.spec.name} finished its run; all stopped cleanly")

    def _fail(self, running: _Running, code: int) -> Outcome:
        what = "failed" if running.spec.primary else "exited unexpectedly"
        reason = f"{running.spec.name} {what} with exit code {code}"
        self._announce(f"{reason}; stopping the others. Last lines of {running.log_path}:")
        self._stop_all()
        for line in running.tail().splitlines():
            self._announce(f"  | {line}")
        return self._outcome(EXIT_FAILURE, reason)

    def _stop_all(self) -> list[str]:
        """Stop every running process, one at a time; return the names stopped uncleanly.

        Stages run from the lowest ``stop_stage`` up, and within a stage the last started
        process is stopped first. Each stop waits :attr:`StopTimeouts.settle`, then escalates
        SIGINT -> SIGTERM -> SIGKILL, and ends before the next process is signalled.
        """
        unclean: list[str] = []
        # sorted() is stable: reversed start order survives within a stage
        for running in sorted(reversed(self._running), key=lambda r: r.spec.stop_stage):
            escalated = False
            if running.popen.poll() is None:
                time.sleep(self._timeouts.settle)
                escalated = self._stop_one(running)
            code = running.popen.returncode
            if escalated or code not in running.spec.clean_exit_codes:
                self._announce(f"{running.spec.name} did not stop cleanly (exit code {code})")
                unclean.append(running.spec.name)
            running.finish_log()
        return unclean

    def _stop_one(self, running: _Running) -> bool:
        """Escalate SIGINT -> SIGTERM -> SIGKILL on its PID; return whether it needed more."""
        steps = (
            (signal.SIGINT, self._timeouts.after_sigint),
            (signal.SIGTERM, self._timeouts.after_sigterm),
            (signal.SIGKILL, 5.0),
        )
        for index, (sig, timeout) in enumerate(steps):
            if index:
                self._announce(f"{running.spec.name} still running; sending {sig.name}")
            with contextlib.suppress(ProcessLookupError):
                os.kill(running.popen.pid, sig)
            with contextlib.suppress(subprocess.TimeoutExpired):
                running.popen.wait(timeout)
            if running.popen.poll() is not None:
                return index > 0
        return True

    def _outcome(self, code: int, reason: str) -> Outcome:
        return Outcome(
            exit_code=code,
            reason=reason,
            exit_codes={r.spec.name: r.popen.returncode for r in self._running},
        )
