"""Section ``lockstep``: plant, thermal and feedforward processes in lockstep."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from common.benchlib import (
    Context,
    Process,
    Record,
    Results,
    Settings,
    plant_speedup,
    processes,
    run_until_exit,
    top_of,
    wait_for_controllers,
)

#: Grids of the lockstep benchmark.
LOCKSTEP_SHAPES = ((12, 12), (32, 32))


def run(context: Context) -> None:
    """Plant, thermal and feedforward processes in lockstep: sim/wall factor, peak memory."""
    from es_bringup.bringup import GraphConfig, node_specs

    settings, results, log_dir = context.settings, context.results, context.log_dir
    for rows, cols in LOCKSTEP_SHAPES:
        n = rows * cols
        speedups: list[float] = []
        peaks: dict[str, list[float]] = {}
        # The thermal node of a 32 x 32 grid takes minutes to start: one run of large grids.
        repeats = settings.repeats if n <= 144 else 1
        for repeat in range(repeats):
            config = GraphConfig(
                scenario="dm_exposure",
                plant={"rows": rows, "cols": cols, "duration": settings.lockstep_duration},
            )
            before, plant_spec = node_specs(config)
            tag = f"{rows}x{cols}_{repeat}"
            started = [Process(f"{s.name}_{tag}", s.command, log_dir) for s in before]
            with processes(*started):
                ready_s = wait_for_controllers(started, 300.0)
                plant = Process(f"{plant_spec.name}_{tag}", plant_spec.command, log_dir)
                with processes(plant):
                    run_until_exit(plant, [*started, plant],
                                    120.0 + 20.0 * settings.lockstep_duration)
            speedup, counts = plant_speedup(plant.output())
            speedups.append(speedup)
            for spec, proc in zip([*before, plant_spec], [*started, plant], strict=True):
                peaks.setdefault(spec.name, []).append(proc.peak_mib)
            results.notes.append(f"lockstep {rows} x {cols} run {repeat + 1}: {speedup:.2f}x "
                                 f"real time; plant counts: {counts}; thermal and feedforward "
                                 f"ready {ready_s:.1f} s after their start")
        results.records.append(Record.of("lockstep_speedup", n, speedups, "sim/wall"))
        for name, values in peaks.items():
            if name != "feedforward":  # the DDS section reports the feedforward's memory
                results.records.append(Record.of(f"peak_rss_{name}", n, values, "MiB"))
    if settings.profile:
        _profile_lockstep(settings, results, log_dir)
    results.notes.append(
        f"lockstep_speedup: dm_exposure at 100 Hz control / 10 Hz sensors, "
        f"{settings.lockstep_duration:g} s sim, plant + thermal (model estimator) + "
        "feedforward (inverse_hyperbolic) as separate processes, the plant's own sim/wall "
        "figure (from its first step to its last)."
    )


def _profile_lockstep(settings: Settings, results: Results, log_dir: Path) -> None:
    """One 12 x 12 lockstep run with the plant and the feedforward node under cProfile."""
    from es_bringup.bringup import GraphConfig, node_specs

    config = GraphConfig(scenario="dm_exposure",
                         plant={"rows": 12, "cols": 12, "duration": settings.lockstep_duration})
    before, plant_spec = node_specs(config)
    modules = {"plant": "es_sim_plant.plant_node", "feedforward": "es_feedforward.feedforward_node",
               "thermal": "es_thermal.thermal_node"}

    def profiled(name: str, command: Sequence[str]) -> list[str]:
        return [sys.executable, "-m", "cProfile", "-o", str(log_dir / f"lockstep_{name}.prof"),
                "-m", modules[name], *command[1:]]

    started = [Process(f"{s.name}_profiled", profiled(s.name, s.command), log_dir)
               for s in before]
    with processes(*started):
        wait_for_controllers(started, 300.0)
        plant = Process("plant_profiled", profiled("plant", plant_spec.command), log_dir)
        with processes(plant):
            run_until_exit(plant, [plant], 120.0 + 20.0 * settings.lockstep_duration)
    for name in ("plant", "feedforward", "thermal"):
        results.profiles[f"{name} node in a 12 x 12 lockstep run"] = top_of(
            log_dir / f"lockstep_{name}.prof", 12)
