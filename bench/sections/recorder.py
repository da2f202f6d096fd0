"""Section ``recorder``: the recorder's memory while it records a 32 x 32 lockstep run."""

from __future__ import annotations

import tempfile
from pathlib import Path

from common.benchlib import (
    Context,
    Process,
    Record,
    plant_speedup,
    processes,
    run_until_exit,
    wait_for_controllers,
)


def run(context: Context) -> None:
    """Peak memory of the recorder while it records a 32 x 32 lockstep run (all /dm topics)."""
    from es_bringup.bringup import GraphConfig, node_specs

    results, log_dir = context.results, context.log_dir
    with tempfile.TemporaryDirectory(prefix="bench_record_") as tmp:
        config = GraphConfig(scenario="dm_exposure", bag=Path(tmp) / "bag",
                             plant={"rows": 32, "cols": 32, "duration": 10.0},
                             thermal={"estimator": "lowpass"})
        before, plant_spec = node_specs(config)
        started = [Process(f"{s.name}_recorded", s.command, log_dir) for s in before]
        with processes(*started):
            wait_for_controllers(started, 300.0)
            plant = Process("plant_recorded", plant_spec.command, log_dir)
            with processes(plant):
                run_until_exit(plant, started, 300.0)
        recorder = started[0]
        results.records.append(Record.of("peak_rss_record", 1024, [recorder.peak_mib], "MiB"))
        speedup, _ = plant_speedup(plant.output())
        results.notes.append(f"peak_rss_record: recorder on every /dm topic and /diagnostics "
                             f"of a 32 x 32 lockstep run of 10 s sim ({speedup:.2f}x real time "
                             "with the recorder; thermal node on the lowpass estimator, which "
                             "starts in seconds).")
