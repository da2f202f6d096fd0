"""The demo's graph runs: jobs run through the bring-up, several at once, each in a namespace.

A :class:`Job` names one graph run (scenario, mode, bag, logs, node parameters); the
:class:`Runner` runs jobs ``jobs`` at a time in one ROS domain, each graph below its own
namespace (``/run0``, ``/run1``, ...; the bags keep the contract's topic names).
"""

from __future__ import annotations

import os
import sys
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from es_bringup.bringup import Bringup, GraphConfig, ParamValue
from es_msgs_py.topics import reserve_domain_id


class Progress:
    """One line per event, prefixed with the elapsed wall time; thread-safe."""

    def __init__(self, stream: Any = sys.stdout) -> None:
        self._start = time.monotonic()
        self._stream = stream
        self._lock = threading.Lock()

    @property
    def elapsed(self) -> float:
        """Seconds since the start."""
        return time.monotonic() - self._start

    def __call__(self, text: str) -> None:
        """Print one progress line."""
        minutes, seconds = divmod(int(self.elapsed), 60)
        with self._lock:
            print(f"[demo {minutes:2d}:{seconds:02d}] {text}", file=self._stream, flush=True)


@dataclass(eq=False)  # identity: a job is one run
class Job:
    """One graph run: what to start and where its bag and logs go."""

    key: str
    scenario: str
    mode: str
    bag: Path
    log_dir: Path
    v_limit: float
    with_controllers: bool = True
    feedforward_params: Path | None = None
    thermal_params: Path | None = None
    plant: dict[str, ParamValue] = field(default_factory=dict)
    thermal: dict[str, ParamValue] = field(default_factory=dict)
    feedforward: dict[str, ParamValue] = field(default_factory=dict)
    record_extra: tuple[str, ...] = ()
    wall_s: float = 0.0


class DemoError(RuntimeError):
    """A step of the demo failed; the message is one readable line."""


class Runner:
    """Run jobs through the bring-up, ``jobs`` at a time, each graph in its own namespace."""

    def __init__(self, jobs: int, domain: int, progress: Progress) -> None:
        self._pool = ThreadPoolExecutor(max_workers=jobs)
        self._domain = domain
        self._free_slots = [f"run{i}" for i in range(jobs)]
        self._lock = threading.Lock()
        self._running: set[Bringup] = set()
        self._progress = progress
        self._stopping = threading.Event()

    def submit(self, job: Job) -> Future[Job]:
        """Queue a job; the future's result is the job with its wall time, or DemoError."""
        return self._pool.submit(self._run, job)

    def _run(self, job: Job) -> Job:
        if self._stopping.is_set():
            raise DemoError("interrupted")
        with self._lock:
            slot = self._free_slots.pop()
        config = GraphConfig(
            scenario=job.scenario,
            mode=job.mode,
            bag=job.bag,
            log_dir=job.log_dir,
            feedforward_params=job.feedforward_params,
            thermal_params=job.thermal_params,
            plant=job.plant,
            thermal=job.thermal,
            feedforward=job.feedforward,
            with_controllers=job.with_controllers,
            domain_id=self._domain,
            namespace=slot,
            wall_timeout=600.0,
            record_extra=job.record_extra,
        )
        bringup = Bringup(config, announce=lambda _text: None)
        with self._lock:
            self._running.add(bringup)
        started = time.monotonic()
        try:
            outcome = bringup.run()
        finally:
            with self._lock:
                self._running.discard(bringup)
                self._free_slots.append(slot)
        job.wall_s = time.monotonic() - started
        if outcome.exit_code != 0:
            raise DemoError(f"{job.key}: {outcome.reason} (logs: {job.log_dir})")
        return job

    def interrupt(self) -> None:
        """Stop every running graph and refuse queued ones."""
        self._stopping.set()
        with self._lock:
            for bringup in self._running:
                bringup.interrupt()

    def shutdown(self) -> None:
        """Wait for the workers to end."""
        self._pool.shutdown(wait=True, cancel_futures=True)


def demo_domain() -> int:
    """Return the demo's ROS domain: ROS_DOMAIN_ID if set, else one no other es_dm process holds."""
    given = os.environ.get("ROS_DOMAIN_ID")
    if given:
        return int(given)
    return reserve_domain_id()
