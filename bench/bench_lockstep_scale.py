"""The closed loop in lockstep at 32 x 32 and 64 x 64: x real time and CPU per step.

Issue 18's lockstep cases: plant, thermal (model estimator) and feedforward processes on the
``dm_exposure`` scenario, the plant started once the controllers are on the graph, so that a
large grid's thermal start-up is not in the figure.

    .venv/bin/python bench/bench_lockstep_scale.py [--seconds 30] [--repeats 1] \
        [--set plant.executor=single_threaded ...]
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from common.benchlib import Results, Settings

    from es_bringup.graph import ParamValue

    #: Extra parameters by node name (one of OVERRIDABLE).
    Overrides = dict[str, dict[str, ParamValue]]

#: Lockstep closed loop (plant + thermal + feedforward processes on dm_exposure): grid and
#: the issue's floor [x real time].
LOCKSTEP_CASES: tuple[tuple[int, int, float], ...] = ((32, 32, 10.0), (64, 64, 5.0))
#: The lockstep nodes whose parameters ``--set`` may override.
OVERRIDABLE = ("plant", "thermal", "feedforward")
#: Longest wait for the thermal and feedforward nodes of a large grid to start [s].
CONTROLLERS_TIMEOUT_S = 600.0


def cpu_seconds(pid: int) -> float:
    """Return the CPU time [s] (user + system) process ``pid`` has used so far (/proc)."""
    import os

    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@dataclass(frozen=True)
class LockstepRun:
    """Figures of one lockstep run.

    Attributes:
        speedup: sim time / wall time of the run (the plant's summary).
        cpu_ms: CPU [ms] per step of each process during the run (plant from its own
            summary; the others from /proc, the plant's start to its exit, their share of
            the plant's start-up included).
        ready_s: how long the thermal and feedforward nodes took to show on the graph [s].

    """

    speedup: float
    cpu_ms: dict[str, float]
    ready_s: float


def lockstep_run(rows: int, cols: int, duration: float, log_dir: Path,
                 overrides: Overrides | None = None) -> LockstepRun:
    """Run the closed loop once (``overrides``: node name -> extra parameters).

    The plant is started only once the thermal and feedforward nodes are on the graph, so
    that their start-up (the thermal model of a large grid) is not in the figure.

    Raises:
        RuntimeError: a node exited, did not start, or the plant printed no summary.

    """
    import re

    from common.benchlib import (
        Process,
        plant_speedup,
        processes,
        run_until_exit,
        wait_for_controllers,
    )

    from es_bringup.bringup import GraphConfig, node_specs

    extra = overrides or {}
    config = GraphConfig(scenario="dm_exposure",
                         plant={"rows": rows, "cols": cols, "duration": duration,
                                **extra.get("plant", {})},
                         thermal=dict(extra.get("thermal", {})),
                         feedforward=dict(extra.get("feedforward", {})))
    before, plant_spec = node_specs(config)
    tag = f"scale_{rows}x{cols}"
    started = [Process(f"{s.name}_{tag}", s.command, log_dir) for s in before]
    with processes(*started):
        ready_s = wait_for_controllers(started, CONTROLLERS_TIMEOUT_S)
        cpu_before = {s.name: cpu_seconds(p.popen.pid)
                      for s, p in zip(before, started, strict=True)}
        plant = Process(f"{plant_spec.name}_{tag}", plant_spec.command, log_dir)
        with processes(plant):
            run_until_exit(plant, [plant], 120.0 + 30.0 * duration)
        cpu_after = {s.name: cpu_seconds(p.popen.pid)
                     for s, p in zip(before, started, strict=True)}
    output = plant.output()
    speedup, _ = plant_speedup(output)
    summary = re.search(r"finished: (\d+) steps.*plant CPU ([\d.]+) ms/step", output)
    steps = int(summary.group(1)) if summary else 0
    cpu_ms = {plant_spec.name: float(summary.group(2)) if summary else float("nan")}
    for name, seconds in cpu_after.items():
        cpu_ms[name] = (seconds - cpu_before[name]) * 1e3 / steps if steps else float("nan")
    return LockstepRun(speedup, cpu_ms, ready_s)


def section_lockstep_scale(settings: Settings, results: Results, log_dir: Path,
                           overrides: Overrides | None = None) -> None:
    """Lockstep closed loop at 32 x 32 and 64 x 64: x real time beside the issue's floors."""
    from common.benchlib import Record, load_note

    for rows, cols, floor in LOCKSTEP_CASES:
        runs = [lockstep_run(rows, cols, settings.lockstep_duration, log_dir, overrides)
                for _ in range(1 if rows * cols > 144 else settings.repeats)]
        speedups = [r.speedup for r in runs]
        results.records.append(Record.of("lockstep_speedup", rows * cols, speedups, "sim/wall"))
        for name in runs[0].cpu_ms:
            results.records.append(Record.of(f"lockstep_{name}_cpu_per_step", rows * cols,
                                              [r.cpu_ms[name] for r in runs], "ms"))
        median = float(np.median(speedups))
        results.notes.append(
            f"{'met' if median >= floor else 'MISSED'}: lockstep {rows} x {cols} >= {floor:g}x "
            f"real time (measured {median:.2f}x; thermal and feedforward took "
            f"{max(r.ready_s for r in runs):.0f} s to start, not counted)")
    results.notes.append(
        f"lockstep (scale): dm_exposure, {settings.lockstep_duration:g} s sim at 100 Hz, plant + "
        "thermal (model estimator) + feedforward processes on one host; "
        "lockstep_<node>_cpu_per_step: each process's CPU per step (plant: its own summary; "
        f"thermal, feedforward: /proc over the plant's run). {load_note()}")


def parse_overrides(items: Sequence[str]) -> Overrides:
    """Parse ``NODE.NAME=VALUE`` items (VALUE as YAML, e.g. ``true``, ``3``) by node.

    Raises:
        SystemExit: an item is not of that form (argparse's one-line error).

    """
    import yaml

    overrides: Overrides = {}
    for item in items:
        key, sep, value = item.partition("=")
        node, dot, name = key.partition(".")
        if not (sep and dot and node in OVERRIDABLE and name):
            raise SystemExit(f"error: --set {item!r}: expected NODE.NAME=VALUE with NODE one "
                             f"of {', '.join(OVERRIDABLE)}")
        overrides.setdefault(node, {})[name] = yaml.safe_load(value)
    return overrides


def main(argv: Sequence[str] | None = None) -> int:
    """Run the lockstep_scale section alone and print its records and notes."""
    from common.benchlib import Results, Settings

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="sim time of each run")
    parser.add_argument("--repeats", type=int, default=1,
                        help="runs of the 32 x 32 case (64 x 64 runs once)")
    parser.add_argument("--log-dir", type=Path, default=Path("out/lockstep_scale"))
    parser.add_argument("--set", action="append", default=[], metavar="NODE.NAME=VALUE",
                        help="a parameter of one node (plant, thermal, feedforward), "
                             "e.g. plant.executor=events; repeatable")
    args = parser.parse_args(argv)
    settings = Settings.create(quick=True, profile=False)
    settings = type(settings)(**{**settings.__dict__, "repeats": args.repeats,
                                 "lockstep_duration": args.seconds})
    results = Results()
    section_lockstep_scale(settings, results, args.log_dir, parse_overrides(args.set))
    results.print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
