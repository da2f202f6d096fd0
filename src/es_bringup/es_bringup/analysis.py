"""Read one closed-loop run back (bag + node logs): aligned data, metrics and invariants.

Pure (rosbags + numpy through ``es_msgs_py.bag``; no rclpy). Used by the demo for every run
and by the system tests.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from es_bringup.errors import RunDataError
from es_bringup.invariants import (
    InvariantReport,
    check_commands,
    check_counts,
    check_recorder,
    published_counts_from_log,
    recorder_counts_from_log,
)
from es_bringup.metrics import (
    AlignedRun,
    PeriodSlots,
    RunMetrics,
    align_run,
    run_metrics,
    setpoint_period,
)
from es_msgs_py import topics
from es_msgs_py.bag import TopicSeries, read_bag
from es_sim_plant.plant import sensor_every

#: Block length used instead of a period when the set point has no AC component, s.
STATIC_BLOCK_S = 1.0
#: Recorder node name: its own last /diagnostics report races its shutdown, so its
#: diagnostics are not part of the published == recorded check (see :func:`check_run`).
RECORDER_NODE = "record"


@dataclass
class RunAnalysis:
    """One run read back: aligned data, figures and what the invariants found."""

    run: AlignedRun
    metrics: RunMetrics
    slots: PeriodSlots
    period_s: float
    invariants: InvariantReport
    sim_s: float


def node_logs(log_dir: Path) -> dict[str, list[str]]:
    """Return the lines of every ``<node>.log`` in ``log_dir`` by node name."""
    return {
        path.stem: path.read_text(encoding="utf-8", errors="replace").splitlines()
        for path in sorted(log_dir.glob("*.log"))
    }


def diagnostics_by_node(series: TopicSeries) -> Counter[str]:
    """Count /diagnostics arrays per reporting node (status names are ``<node>: <aspect>``)."""
    counts: Counter[str] = Counter()
    for message in series.messages:
        names = {status.name.split(":", 1)[0] for status in message.status}
        for name in names:
            counts[name] += 1
    return counts


def check_run(
    bag: Mapping[str, TopicSeries],
    logs: Mapping[str, Iterable[str]],
    v_limit: float,
    data_topics: Iterable[str] = topics.DM_TOPICS,
) -> InvariantReport:
    """Check a run's invariants: commands finite and within ``v_limit``; nothing lost.

    Data topics (/dm): the published counts summed over the nodes' exit logs must equal the
    bag's (the plant starts only when the recorder has matched every topic it publishes).
    Every topic: the recorder wrote all it received and the middleware reported no loss.
    /diagnostics, per publishing node (the bag's arrays are attributed by their status
    names): the bag may lack only reports sent before the recorder had matched that node
    (start-up, volatile QoS), which are counted; more in the bag than published fails. The
    recorder's own reports are left out (its last one races its shutdown).
    """
    report = InvariantReport()
    command = bag.get(topics.COMMAND)
    if command is not None and command.values is not None:
        check_commands(command.values, v_limit, report)
    elif command is None:
        report.failures.append(f"{topics.COMMAND}: not in the bag")
    published: Counter[str] = Counter()
    names = tuple(topics.TOPIC_TYPES)
    per_node = {node: published_counts_from_log(lines, names) for node, lines in logs.items()}
    for counts in per_node.values():
        published.update(counts)
    in_bag = {topic: len(series) for topic, series in bag.items()}
    wanted = [t for t in data_topics if t in in_bag or published.get(t)]
    check_counts(published, in_bag, report, wanted)
    check_recorder(recorder_counts_from_log(logs.get(RECORDER_NODE, [])), report)
    if topics.DIAGNOSTICS in bag:
        recorded = diagnostics_by_node(bag[topics.DIAGNOSTICS])
        for node, counts in per_node.items():
            sent = counts.get(topics.DIAGNOSTICS)
            if node == RECORDER_NODE or sent is None:
                continue
            got = recorded.get(node, 0)
            if got > sent:
                report.failures.append(
                    f"{topics.DIAGNOSTICS}: {got} reports of {node} in the bag, {sent} published"
                )
            report.diagnostics_before_recording[node] = sent - got
    return report


def analyse_run(
    bag_path: Path,
    log_dir: Path,
    v_limit: float,
    *,
    control_rate: float,
    sensor_rate: float,
    period_s: float | None = None,
) -> RunAnalysis:
    """Read a closed-loop run's bag and logs; return its metrics and invariants.

    Times come from the lockstep protocol, not from the bag's stamps (the recorder's sim
    clock at reception lags under load): displacement i at i / ``control_rate``, estimate
    j at the sensor step j * sensor_every(control_rate, sensor_rate). ``period_s`` is the set
    point's period when known; by default it is found from the set point
    (:func:`setpoint_period`).

    Raises:
        es_msgs_py.bag.BagError: the bag is unreadable or lacks a needed topic.
        RunDataError: the run is too short or its topics do not fit the lockstep protocol.

    """
    bag = read_bag(bag_path)
    needed = (topics.DISPLACEMENT, topics.SETPOINT, topics.TEMPERATURE)
    missing = [t for t in needed if t not in bag or bag[t].values is None]
    if missing:
        raise RunDataError(f"{bag_path}: no {', '.join(missing)} recorded")
    disp, sp, temp = (bag[t].values for t in needed)
    assert disp is not None and sp is not None and temp is not None
    every = sensor_every(control_rate, sensor_rate)
    disp_times = np.arange(len(disp)) / control_rate
    temp_times = np.arange(len(temp)) * every / control_rate
    run = align_run(disp_times, disp, sp, temp_times, temp)
    period = period_s or setpoint_period(run.times, run.setpoint) or STATIC_BLOCK_S
    metrics, slots = run_metrics(run, period, skip_s=period)
    invariants = check_run(bag, node_logs(log_dir), v_limit)
    sim_s = float(disp_times[-1]) if len(disp_times) else 0.0
    return RunAnalysis(run, metrics, slots, period, invariants, sim_s)
