"""Run one rclpy node as a process: clean shutdown on SIGINT/SIGTERM, one-line errors.

SIGINT and SIGTERM are taken over from rclpy (:class:`StopSignals`): the handler only
records the signal, the spin loop sees it within :data:`SPIN_SLICE` and ends, and the node is
closed, destroyed and rclpy shut down in that order on the main thread, with the context still
valid until the end. rclpy's own handlers shut the context down from a thread of their own
and trigger the executors' guard conditions there, while the main thread goes on closing
the node and collecting garbage: that thread crashed the process with SIGSEGV in
``rcl_trigger_guard_condition`` in 3 of 133 recorder Ctrl-C stops on a loaded machine.

Once the node is built, before it spins, the start-up's garbage is collected and every object
left is frozen out of the garbage collector's reach (:func:`settle_garbage`): the imports, the
node, compiled kernels are never scanned again, and a collection while messages are served
walks only what was allocated since. Measured with the feedforward node at 128 x 128 (a
loaded machine): its one young (generation 1) collection per 10 s of 1 kHz set points took
0.9-1.0 ms, frozen 0.1 ms; an unfrozen full collection took 17-24 ms.

Fast DDS gets the es_dm profile (:func:`es_node_runtime.middleware.configure_middleware`: a
shared-memory segment that holds a hundred 128 x 128 grids) unless the environment names one.

A node picks its executor with a read-only ``executor`` parameter (see :data:`EXECUTORS`);
nodes without it get rclpy's ``SingleThreadedExecutor``.

Before the teardown a node waits, bounded (:data:`DELIVERY_LIMIT`), until every matched reader
has acknowledged what its reliable publishers sent (:func:`deliver_pending`), and names the
topics where one has not: a writer destroyed earlier takes the messages a busy reader still
needed repaired with it.

A node that receives what others publish (a recorder) can ask for its inputs to be drained
at a stop request: it is :class:`Draining`, and the executor goes on serving it, bounded
(:data:`DRAIN_LIMIT`), until it says it is settled, before it is closed.

The DDS teardown at the end is bounded (:data:`TEARDOWN_LIMIT`): Fast DDS 2.14 can hang for
good while it destroys a participant that is handling another participant's goodbye at that
moment (several nodes stopped at once). The node's own work is finished and flushed by then;
instead of waiting for a SIGKILL, the process prints where it hung and exits 1. A native
crash (SIGSEGV, SIGABRT) prints the Python stack of every thread (``faulthandler``).

``--help``/``-h`` (before any ``--ros-args``) prints the node's usage and parameters and exits
0 without initialising ROS.
"""

from __future__ import annotations

import faulthandler
import gc
import signal
import sys
import time
from collections.abc import Callable, Sequence
from types import FrameType, TracebackType
from typing import Final, Protocol, runtime_checkable

import rclpy
import rclpy.logging
from rclpy._rclpy_pybind11 import RCLError
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from es_node_runtime.errors import ParameterValueError
from es_node_runtime.middleware import configure_middleware
from es_node_runtime.param_spec import ParameterSpec

#: Name of the read-only parameter through which a node chooses its executor.
EXECUTOR_PARAMETER: Final = "executor"
#: ``single_threaded``: rclpy's SingleThreadedExecutor, which rebuilds its wait set in Python
#: on every wake-up. ``events``: rclpy's experimental EventsExecutor (C++ event queue,
#: callbacks in arrival order), several times cheaper per message.
EXECUTORS: Final = ("single_threaded", "events")
#: The executor every node spins on unless its ``executor`` parameter says otherwise.
DEFAULT_EXECUTOR: Final = "events"
#: Longest time [s] an executor waits without returning to Python, where a stop request
#: (:class:`StopSignals`) and the context are checked: the longest delay of a Ctrl-C.
SPIN_SLICE: Final = 0.1
#: The signals that stop a node cleanly.
STOP_SIGNALS: Final = (signal.SIGINT, signal.SIGTERM)
#: Longest time [s] the DDS teardown (destroying the node, shutting rclpy down) may take
#: before the process gives up on it: normally well under a second.
TEARDOWN_LIMIT: Final = 5.0
#: Longest time [s], all publishers together, a stopping node waits for its reliable
#: publishers' messages to be acknowledged by every matched reader. A reader that missed
#: messages under load gets them again only on the writer's next heartbeat (Fast DDS: 3 s),
#: and a writer destroyed before that takes them with it (33 of 350 commands never reached a
#: recorder in a stress run). Normally nothing is pending and the wait returns at once.
DELIVERY_LIMIT: Final = 4.0


#: Longest time [s] a :class:`Draining` node is served after a stop request until it is
#: settled: well within the bring-up's 10 s between SIGINT and SIGTERM.
DRAIN_LIMIT: Final = 5.0


@runtime_checkable
class Draining(Protocol):
    """A node that must take what is already on its way to it before it closes."""

    def settled(self) -> bool:
        """Return whether nothing more is expected (the executor stops serving it then)."""
        ...


class PublishCounter:
    """Count the messages a node publishes, per topic, through the publishers it has.

    Wraps ``publish`` of every publisher the node created so far (nodes create theirs in the
    constructor). The counts are what the bring-up compares with a bag's message counts to
    prove that nothing published on a recorded topic was lost on the way.
    """

    def __init__(self, node: Node) -> None:
        self.counts: dict[str, int] = {}
        for publisher in node.publishers:
            self._wrap(publisher)

    def _wrap(self, publisher: Publisher) -> None:
        topic = publisher.topic_name
        self.counts.setdefault(topic, 0)
        publish = publisher.publish

        def counted(msg: object) -> None:
            publish(msg)
            self.counts[topic] += 1

        publisher.publish = counted  # type: ignore[method-assign]

    def log_lines(self) -> list[str]:
        """Return ``published <topic>: <count>`` for every topic, sorted by topic."""
        return [f"published {topic}: {count}" for topic, count in sorted(self.counts.items())]


def executor_spec(default: str = DEFAULT_EXECUTOR) -> ParameterSpec:
    """Return the read-only ``executor`` parameter a node declares to choose its executor.

    Args:
        default: the node's default, one of :data:`EXECUTORS`.

    """
    return ParameterSpec(
        EXECUTOR_PARAMETER,
        default,
        "Executor: 'events' (rclpy's experimental EventsExecutor, several times cheaper per "
        "message) or 'single_threaded' (rclpy's default, as a fallback).",
        choices=EXECUTORS,
        read_only=True,
    )
class StopSignals:
    """SIGINT/SIGTERM as a stop request: within ``with``, the handler only records the signal.

    Nothing is shut down or finalised from the handler (Python runs it on the main thread
    between two bytecodes); whoever spins polls :attr:`received`. A later signal, e.g. the
    SIGTERM that ``ros2 launch`` sends when a stop takes long, changes nothing: the teardown
    is bounded by the watchdog of :func:`run_node` instead. The previous handlers are
    restored on leaving the ``with`` block.
    """

    def __init__(self) -> None:
        #: the first stop signal received (``signal.SIGINT``...), ``None`` before any
        self.received: int | None = None
        self._previous: dict[int, object] = {}

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        if self.received is None:
            self.received = signum

    def __call__(self) -> bool:
        """Return whether a stop signal has been received."""
        return self.received is not None

    def __enter__(self) -> StopSignals:
        for sig in STOP_SIGNALS:
            self._previous[sig] = signal.signal(sig, self._on_signal)
        return self

    def __exit__(
        self,
        _type: type[BaseException] | None,
        _value: BaseException | None,
        _traceback: TracebackType | None,
    ) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]  # what signal() returned


def settle_garbage() -> None:
    """Collect the garbage there is, then freeze what is left (``gc.freeze``).

    Call once a long-running process is built: later collections skip every object frozen
    here (they stay alive for good, like the imports and the node do anyway).
    """
    gc.collect()
    gc.freeze()


def executor_kind(node: Node) -> str:
    """Return the executor ``node`` asks for (its ``executor`` parameter, if declared).

    Raises:
        ParameterValueError: the parameter names no known executor.

    """
    if not node.has_parameter(EXECUTOR_PARAMETER):
        return EXECUTORS[0]
    kind = node.get_parameter(EXECUTOR_PARAMETER).value
    if kind not in EXECUTORS:
        raise ParameterValueError(f"{EXECUTOR_PARAMETER}={kind!r} is not one of {list(EXECUTORS)}")
    return str(kind)


def spin(
    node: Node,
    kind: str = EXECUTORS[0],
    context: Context | None = None,
    stopped: Callable[[], bool] = lambda: False,
) -> None:
    """Spin ``node`` with the executor ``kind`` (one of :data:`EXECUTORS`) until shutdown.

    The spin ends when the context shuts down or, at the latest :data:`SPIN_SLICE` seconds
    after, when ``stopped()`` becomes true (e.g. a :class:`StopSignals`); a
    :class:`Draining` node is then served on until it is settled, at most
    :data:`DRAIN_LIMIT` seconds. ``events`` falls
    back to the single-threaded executor, with a warning, on an rclpy without the
    EventsExecutor. Raises ``KeyboardInterrupt`` or ``ExternalShutdownException`` like
    ``rclpy.spin``.
    """
    context = context or node.context
    executor: Executor | None = None
    if kind == "events":
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:  # rclpy before 7.1.4 (Jazzy before April 2025)
            node.get_logger().warning(
                "this rclpy has no EventsExecutor (7.1.4 or later has): spinning single-threaded"
            )
        else:
            executor = EventsExecutor(context=context)
    if executor is None:
        executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    while context.ok() and not stopped():
        executor.spin_once(timeout_sec=SPIN_SLICE)
    if isinstance(node, Draining):
        # a stop request: what is already on its way is taken, bounded, before the close
        deadline = time.monotonic() + DRAIN_LIMIT
        while context.ok() and not node.settled() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=SPIN_SLICE)


def wants_help(args: Sequence[str]) -> bool:
    """Return whether ``args`` (program name first) ask for help before any ROS arguments."""
    own = list(args[1:])
    if "--ros-args" in own:
        own = own[: own.index("--ros-args")]
    return "-h" in own or "--help" in own


def usage_text(program: str, summary: str, specs: Sequence[ParameterSpec] = ()) -> str:
    """Return the ``--help`` text of a node executable: usage, summary and its parameters.

    Args:
        program: executable name as ``ros2 run`` knows it, e.g. ``es_thermal thermal_node``.
        summary: what the node does (a paragraph).
        specs: the node's declared parameters (name, default, description with units).

    """
    lines = [
        f"usage: ros2 run {program} [--ros-args -p NAME:=VALUE ... --params-file FILE]",
        "",
        summary.strip(),
    ]
    if specs:
        lines += ["", "parameters (name, default: description):"]
        for spec in specs:
            text = spec.full_description()
            lines.append(f"  {spec.name} ({spec.default!r}): {text}")
    return "\n".join(lines) + "\n"


def deliver_pending(node: Node, limit: float = DELIVERY_LIMIT) -> list[str]:
    """Wait until every reliable publisher's messages are acknowledged by its readers.

    Bounded by ``limit`` seconds for all publishers together. Returns the topics whose
    messages some matched reader has still not acknowledged (a reader that is stopped,
    starved or dead: its loss then shows in the counts, and the caller says so).
    """
    deadline = time.monotonic() + limit
    pending = []
    for publisher in list(node.publishers):
        if publisher.qos_profile.reliability != ReliabilityPolicy.RELIABLE:
            continue
        left = Duration(seconds=max(deadline - time.monotonic(), 0.0))
        if not publisher.wait_for_all_acked(left):
            pending.append(publisher.topic_name)
    return pending


def deliver_and_report(node: Node, limit: float = DELIVERY_LIMIT) -> list[str]:
    """:func:`deliver_pending`, and a summary line naming the topics still unacknowledged.

    What a node calls before its publishers go (a stop, or the end of its own run): the
    topics it returns are the ones where some reader may lack messages for good.
    """
    unacknowledged = deliver_pending(node, limit)
    if unacknowledged:
        summary_line(node.get_name(), f"not acknowledged by every reader within {limit:g} s "
                     f"at the stop: {', '.join(unacknowledged)}")
    return unacknowledged


def summary_line(node_name: str, text: str) -> None:
    """Print one exit-summary line to stderr, formatted like an rcutils log line.

    ``[INFO] [<unix time>] [<node_name>.summary]: <text>``. Printed, not logged: under
    ``ros2 launch`` every node is stopped at once, and logging through rcutils while rclpy
    and the middleware shut down (their own threads) crashed a node with SIGSEGV now and then.
    """
    print(f"[INFO] [{time.time():.9f}] [{node_name}.summary]: {text}", file=sys.stderr,
          flush=True)  # fmt: skip


def run_node(
    make_node: Callable[[], Node],
    args: Sequence[str] | None = None,
    teardown_limit: float = TEARDOWN_LIMIT,
    *,
    help_text: str = "",
) -> int:
    """Create the node with ``make_node``, spin it until shutdown and return an exit code.

    SIGINT and SIGTERM end the spin cleanly (:class:`StopSignals`; rclpy's own handlers are
    not installed, so the context stays valid until the node is closed and destroyed);
    the node spins on the executor its ``executor`` parameter names (:func:`executor_kind`);
    the node's ``close()`` runs if it has one, then the node logs how many messages it
    published per topic (``published <topic>: <count>``, see :class:`PublishCounter`). An
    invalid configuration (``ValueError`` from the constructor) prints one readable line and
    returns 2. A DDS teardown that takes longer than ``teardown_limit`` seconds ends the
    process with exit code 1 and the Python stack it hung in on stderr. With ``--help`` it
    prints ``help_text`` (see :func:`usage_text`) and returns 0 without starting the node.
    """
    argv = list(args) if args is not None else sys.argv
    if help_text and wants_help(argv):
        sys.stdout.write(help_text)
        return 0
    # A native crash (e.g. SIGSEGV in a DDS teardown) prints every thread's stack.
    faulthandler.enable()
    configure_middleware()
    with StopSignals() as stop:
        try:
            rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
        except RCLError as err:  # e.g. a --params-file that does not exist or does not parse
            print(f"error: {str(err).splitlines()[0]}", file=sys.stderr)
            return 2
        return _run(make_node, stop, teardown_limit)


def _run(make_node: Callable[[], Node], stop: StopSignals, teardown_limit: float) -> int:
    """Create, spin, close and destroy the node, then shut rclpy down (see :func:`run_node`)."""
    node: Node | None = None
    counter: PublishCounter | None = None
    try:
        node = make_node()
        counter = PublishCounter(node)
        settle_garbage()
        spin(node, executor_kind(node), stopped=stop)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # rclpy 7.1 can fail a message take that races the context's shutdown ("Unable to
        # convert call argument", seen in 1 of 50 Ctrl-C stops): that is the stop itself, and
        # so is a Ctrl-C while the node is still being built (its next rcl call fails with
        # "context is invalid"). With the context still up it is a real error.
        if node.context.ok() if node is not None else rclpy.ok():
            raise
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    finally:
        if node is not None:
            close = getattr(node, "close", None)
            if callable(close):
                close()
            if counter is not None:
                for line in counter.log_lines():
                    summary_line(node.get_name(), line)
            if node.context.ok():
                deliver_and_report(node)
        # A C-level watchdog: a hung teardown holds the GIL, so no Python thread could act.
        faulthandler.dump_traceback_later(teardown_limit, exit=True)
        try:
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
        finally:
            faulthandler.cancel_dump_traceback_later()
    return 0
