"""A node's readiness, followed until nothing is left to wait for (the nodes' one check).

A node is ready when its inputs have matched a publisher and its outputs the subscriptions it
was told to expect (what is missing: :func:`es_msgs_py.diagnostics.unmatched` and
``unreached``). :class:`Readiness` asks the node what it still waits for on a wall-clock
timer, tells the node at once when that changes (it republishes its diagnostics), and stops
checking once nothing is missing. The thermal and feedforward nodes use it alike.
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

__all__ = ["Readiness"]


class Readiness:
    """What a node waits for before it is ready, checked every ``period`` seconds (wall)."""

    def __init__(
        self,
        node: Node,
        waiting_for: Callable[[], list[str]],
        on_change: Callable[[], None],
        period: float,
        on_ready: Callable[[], None] | None = None,
    ) -> None:
        """Start following ``waiting_for()`` on ``node``.

        Args:
            node: the node whose timer checks.
            waiting_for: returns what readiness still waits for, empty when ready.
            on_change: called right after that list changed (publish the diagnostics).
            period: seconds between checks, on a steady clock (not the node's sim time).
            on_ready: called once when nothing is left to wait for.

        """
        self._waiting_for = waiting_for
        self._on_change = on_change
        self._on_ready = on_ready
        #: What readiness waits for now; empty once the node is ready.
        self.waiting: list[str] = waiting_for()
        self._timer = node.create_timer(
            period, self._check, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )

    def _check(self) -> None:
        waiting = self._waiting_for()
        if waiting != self.waiting:
            self.waiting = waiting
            self._on_change()
        if not waiting:
            self._timer.cancel()
            if self._on_ready is not None:
                self._on_ready()
