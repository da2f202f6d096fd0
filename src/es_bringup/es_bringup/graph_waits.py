"""The bring-up's readiness waits on the ROS graph, bounded, each naming what never came.

:func:`wait_for_subscriptions`: the nodes started before the plant show their subscriptions
(the bring-up starts the plant only then); :func:`wait_for_recorder`: a test stand's recorder
reports on /diagnostics that it received everything the plant published. Each runs a probe
node in its own rclpy context (graphs may run side by side in one process).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Mapping, Sequence

from es_bringup.graph import RECORDER, scoped
from es_bringup.supervisor import Supervisor
from es_msgs_py import topics

#: How long a recorder's counts may stand still before :func:`wait_for_recorder` stops
#: waiting [s].
DRAIN_IDLE_S = 3.0


def _probe_name(base: str) -> str:
    """Return a node name unique to this process and thread (graphs may run side by side)."""
    return f"{base}_{os.getpid()}_{threading.get_ident() % 100000}"


def wait_for_recorder(
    published: Mapping[str, int],
    timeout: float,
    domain_id: int | None = None,
    namespace: str | None = None,
) -> bool:
    """Wait until a recorder report on /diagnostics shows ``published`` all received.

    Returns False after ``timeout`` or once the recorder's counts stood still for
    ``DRAIN_IDLE_S`` (it will not get the rest: the invariants check will tell what is missing).
    """
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    done = False
    last_counts: list[str] | None = None
    changed = time.monotonic()

    def on_report(msg: DiagnosticArray) -> None:
        nonlocal done, last_counts, changed
        for status in msg.status:
            if not status.name.startswith(f"{RECORDER}:"):
                continue
            received = {kv.key: kv.value for kv in status.values}
            counts = [received.get(f"{t} received", "") for t in published]
            if counts != last_counts:
                last_counts, changed = counts, time.monotonic()
            wanted = published.values()
            if all(c.isdigit() and int(c) >= n for c, n in zip(counts, wanted, strict=True)):
                done = True

    context = rclpy.Context()
    rclpy.init(
        args=[], context=context, domain_id=domain_id,
        signal_handler_options=SignalHandlerOptions.NO,
    )  # fmt: skip
    node = rclpy.create_node(_probe_name("bringup_drain"), context=context)
    node.create_subscription(
        DiagnosticArray,
        scoped(topics.DIAGNOSTICS, namespace),
        on_report,
        topics.qos_for(topics.DIAGNOSTICS),
    )
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    deadline = time.monotonic() + timeout
    try:
        while not done and time.monotonic() < deadline:
            if time.monotonic() - changed > DRAIN_IDLE_S:
                break
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
    return done


def wait_for_subscriptions(
    expected: Mapping[str, Sequence[str]],
    timeout: float,
    supervisor: Supervisor,
    interrupted: threading.Event,
    *,
    domain_id: int | None = None,
    node_namespace: str = "/",
) -> str | None:
    """Wait until every node in ``expected`` shows its subscriptions on the ROS graph.

    Returns ``None`` when ready, else a one-line reason (timeout, a node died, interrupted).
    """
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    context = rclpy.Context()
    rclpy.init(
        args=[],  # not sys.argv: the bring-up's own arguments are no ROS arguments
        context=context,
        domain_id=domain_id,
        # the bring-up's own SIGINT/SIGTERM handling stops the graph; rclpy must not
        signal_handler_options=SignalHandlerOptions.NO,
    )
    node = rclpy.create_node(_probe_name("bringup_probe"), context=context)
    deadline = time.monotonic() + timeout
    try:
        missing: dict[str, set[str]] = {}
        while time.monotonic() < deadline:
            failed = supervisor.check_alive()
            if failed is not None:
                return failed.reason
            if interrupted.is_set():
                return "interrupted during start-up"
            names = {n for n, ns in node.get_node_names_and_namespaces() if ns == node_namespace}
            missing = {}
            for name, wanted in expected.items():
                have: set[str] = set()
                if name in names:
                    have = {
                        t
                        for t, _ in node.get_subscriber_names_and_types_by_node(
                            name, node_namespace
                        )
                    }
                if not set(wanted) <= have:
                    missing[name] = set(wanted) - have
            if not missing:
                return None
            time.sleep(0.05)
        what = "; ".join(
            f"{n} not subscribed to {', '.join(sorted(t))}" for n, t in missing.items()
        )
        return f"nodes not ready after {timeout:g} s: {what}"
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
