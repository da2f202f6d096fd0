"""Run one rclpy node as a process: clean shutdown on SIGINT/SIGTERM, one-line errors."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from typing import Protocol

import rclpy
import rclpy.logging
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher


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


class Closable(Protocol):
    """A node with resources to release before the process exits (bags, files)."""

    def close(self) -> None:
        """Flush and release everything; called once, after spinning stopped."""


def run_node(make_node: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Create the node with ``make_node``, spin it until shutdown and return an exit code.

    SIGINT and SIGTERM end the spin cleanly (rclpy's signal handlers shut the context down);
    the node's ``close()`` runs if it has one, then the node logs how many messages it
    published per topic (``published <topic>: <count>``, see :class:`PublishCounter`). An
    invalid configuration (``ValueError`` from the constructor) prints one readable line and
    returns 2.
    """
    try:
        rclpy.init(args=list(args) if args is not None else sys.argv)
    except RCLError as err:  # e.g. a --params-file that does not exist or does not parse
        print(f"error: {str(err).splitlines()[0]}", file=sys.stderr)
        return 2
    node: Node | None = None
    counter: PublishCounter | None = None
    try:
        node = make_node()
        counter = PublishCounter(node)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    finally:
        if node is not None:
            close = getattr(node, "close", None)
            if callable(close):
                close()
            if counter is not None:
                # A plain logger: the node's own would try /rosout after shutdown.
                summary = rclpy.logging.get_logger(f"{node.get_name()}.summary")
                for line in counter.log_lines():
                    summary.info(line)
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
