"""Run one rclpy node as a process: clean shutdown on SIGINT/SIGTERM, one-line errors."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from typing import Protocol

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node


class Closable(Protocol):
    """A node with resources to release before the process exits (bags, files)."""

    def close(self) -> None:
        """Flush and release everything; called once, after spinning stopped."""


def run_node(make_node: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Create the node with ``make_node``, spin it until shutdown and return an exit code.

    SIGINT and SIGTERM end the spin cleanly (rclpy's signal handlers shut the context down);
    the node's ``close()`` runs if it has one. An invalid configuration (``ValueError`` from
    the constructor) prints one readable line and returns 2.
    """
    rclpy.init(args=list(args) if args is not None else sys.argv)
    node: Node | None = None
    try:
        node = make_node()
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
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
