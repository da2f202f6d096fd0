"""Start installed node executables as processes and talk to them over DDS.

Processes are started from the installed ``<prefix>/lib/<pkg>/<exe>`` launchers (what
``ros2 run`` would run) and ended by their own PID only; they inherit the isolated
ROS_DOMAIN_ID of the test process (see tests/conftest.py).

Readiness is a fact, not a sleep: :func:`wait_matched` (a test's own publishers and
subscriptions have matched their peers), :func:`wait_until` (first data or a handshake) and
:func:`poll_until` (a file, a process) wait at most ``READY_TIMEOUT`` and fail with
:class:`NotReadyError` naming what never matched or came.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO

import rclpy
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.subscription import Subscription

PREFIX = Path(sys.prefix)

#: One bounded wait for DDS readiness (endpoints matched, first data), wall seconds. Generous:
#: discovery on a loaded machine takes seconds; a wait that ends early costs nothing.
READY_TIMEOUT = 60.0


#: Wall seconds a node gets from SIGINT to its exit before SIGKILL. Generous: a node's teardown
#: (executor, DDS participant) takes seconds on a loaded machine, and a test that asserts a
#: clean exit must not see a SIGKILL of a node that was still stopping cleanly.
STOP_TIMEOUT = 30.0


class NotReadyError(AssertionError):
    """A DDS endpoint never matched, or awaited data never came, within the bounded wait."""


def executable(package: str, name: str) -> Path:
    """Return the installed launcher ``<prefix>/lib/<package>/<name>``."""
    return PREFIX / "lib" / package / name


class NodeProcess:
    """A node process started by a test; output goes to a temporary log file."""

    def __init__(self, package: str, name: str, args: Sequence[str] = ()) -> None:
        self.command = [str(executable(package, name)), *args]
        self._log: IO[bytes] = tempfile.TemporaryFile()  # noqa: SIM115 - lives as long as the process
        self.process = subprocess.Popen(
            self.command, stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True
        )

    @property
    def pid(self) -> int:
        """The PID of the started process."""
        return self.process.pid

    def output(self) -> str:
        """Return everything the process printed so far."""
        self._log.seek(0)
        return self._log.read().decode(errors="replace")

    def stop(self, sig: int = signal.SIGINT, timeout: float = STOP_TIMEOUT) -> int:
        """Send ``sig`` to this process only, wait for it, and return its exit code."""
        if self.process.poll() is None:
            os.kill(self.process.pid, sig)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                os.kill(self.process.pid, signal.SIGKILL)
                self.process.wait(timeout)
        return self.process.returncode


@contextmanager
def node_process(package: str, name: str, args: Sequence[str] = ()) -> Iterator[NodeProcess]:
    """Run a node process for the duration of the ``with`` block; stop it afterwards."""
    proc = NodeProcess(package, name, args)
    try:
        yield proc
    finally:
        proc.stop()


@contextmanager
def test_node(name: str = "es_test") -> Iterator[Node]:
    """Yield an rclpy node in a fresh context of this process; shut it down afterwards."""
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node(name, context=context)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def spin_until(node: Node, done: Callable[[], bool], timeout: float) -> bool:
    """Spin ``node`` until ``done()`` is true or ``timeout`` seconds pass; return ``done()``."""
    executor = rclpy.executors.SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    deadline = time.monotonic() + timeout
    try:
        while not done() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.remove_node(node)
    return done()


def matched(endpoint: Publisher | Subscription) -> int:
    """Peers matched by ``endpoint``: subscriptions of a publisher, publishers of a subscription."""
    if isinstance(endpoint, Publisher):
        return endpoint.get_subscription_count()
    return endpoint.get_publisher_count()


def unmatched(wanted: Iterable[tuple[Publisher | Subscription, int]]) -> list[str]:
    """Describe every endpoint of ``(endpoint, peers wanted)`` that matched fewer peers."""
    out = []
    for endpoint, count in wanted:
        have = matched(endpoint)
        if have < count:
            kind, peers = (
                ("publisher", "subscriptions")
                if isinstance(endpoint, Publisher)
                else ("subscription", "publishers")
            )
            out.append(f"{kind} {endpoint.topic_name}: {have} of {count} {peers} matched")
    return out


def wait_until(
    node: Node,
    done: Callable[[], bool],
    what: str,
    timeout: float = READY_TIMEOUT,
    processes: Iterable[NodeProcess] = (),
) -> None:
    """Spin ``node`` until ``done()``; fail naming ``what`` never came.

    Raises:
        NotReadyError: ``timeout`` seconds passed, or one of ``processes`` exited first (its
            output is in the message).

    """
    watched = list(processes)
    deadline = time.monotonic() + timeout
    while not done():
        for proc in watched:
            if proc.process.poll() is not None:
                raise NotReadyError(
                    f"{what}: never came; {proc.command[0]} exited "
                    f"{proc.process.returncode} first:\n{proc.output()}"
                )
        if time.monotonic() >= deadline:
            raise NotReadyError(f"{what}: never came within {timeout:g} s")
        spin_until(node, done, timeout=min(0.2, max(deadline - time.monotonic(), 0.0)))


def poll_until(done: Callable[[], bool], what: str, timeout: float = READY_TIMEOUT) -> None:
    """Poll ``done()`` every 50 ms (no ROS node involved, e.g. a file being written).

    Raises:
        NotReadyError: ``timeout`` seconds passed without ``done()``.

    """
    deadline = time.monotonic() + timeout
    while not done():
        if time.monotonic() >= deadline:
            raise NotReadyError(f"{what}: never came within {timeout:g} s")
        time.sleep(0.05)


def wait_matched(
    node: Node,
    endpoints: Iterable[Publisher | Subscription],
    count: int = 1,
    timeout: float = READY_TIMEOUT,
    processes: Iterable[NodeProcess] = (),
) -> None:
    """Spin ``node`` until each endpoint has matched ``count`` peers (subscriptions of a
    publisher, publishers of a subscription).

    Raises:
        NotReadyError: within ``timeout`` seconds some endpoint did not match (the message
            names each such endpoint and its matched count), or a watched process exited.

    """
    wanted = [(endpoint, count) for endpoint in endpoints]
    try:
        wait_until(node, lambda: not unmatched(wanted), "endpoints matched", timeout, processes)
    except NotReadyError as err:
        raise NotReadyError(f"{err} ({'; '.join(unmatched(wanted))})") from None
