"""Section ``teardown``: Ctrl-C stops of the graph, and of the recorder alone.

Under ros2 launch and the bring-up (bench_teardown.py); the recorder while messages are in
flight (bench_recorder_stops.py).
"""

from __future__ import annotations

from common.benchlib import Context, Record


def run(context: Context) -> None:
    """Ctrl-C stops under ros2 launch and the bring-up (bench_teardown.py): crashes, times."""
    from bench_teardown import ros2_executable, teardown_stops

    results = context.results
    # a sample of the stops by default (each bring-up stop takes about 13 s); --full: 50 each
    stops = 50 if context.full else 2 if context.quick else 5
    kinds = ["launch", "bringup"] if ros2_executable() else ["bringup"]
    if "launch" not in kinds:
        results.failures.append("teardown: no ros2 for the launch stops (scripts/ros2cli-env)")
    for kind in kinds:
        outcome = teardown_stops(kind, stops)
        results.records.append(
            Record.of(f"teardown_crashes_{kind}", outcome.stops, [outcome.crashes], "crashes"))
        if outcome.stop_seconds:
            results.records.append(Record.of(f"teardown_stop_time_{kind}", outcome.stops,
                                             outcome.stop_seconds, "s"))
        results.notes += [f"teardown {kind} {note}" for note in outcome.crash_notes]
    results.notes.append(
        f"teardown: {stops} Ctrl-C stops (SIGINT to the ros2 launch / bringup PID) of a "
        "dm_exposure 12 x 12 lockstep graph with recorder, each 0.2-2 s after the feedforward "
        "was ready; a crash = a node died or printed a native stack, an unclean exit, a stop "
        "over 90 s or an unclosed bag; stop time = SIGINT to exit (median, min-max)."
    )
    from bench_recorder_stops import recorder_stops

    storm = recorder_stops(stops, cpu_hogs=2)
    results.records.append(Record.of("teardown_crashes_recorder", storm.stops, [storm.crashes],
                                     "crashes"))  # fmt: skip
    if storm.stop_seconds:
        results.records.append(Record.of("teardown_stop_time_recorder", storm.stops,
                                         storm.stop_seconds, "s"))  # fmt: skip
    results.notes += [f"teardown recorder {note}" for note in storm.crash_notes]
    results.notes.append(
        f"teardown recorder: {stops} SIGINT stops of `record` (3 topics) while publishing at "
        f"about 1 kHz, 0.1-1 s after it said ready, 2 CPU hogs beside it (load average "
        f"{storm.load_average} at the end); a crash = exit not 0, a native stack, a stop over "
        "30 s or an unclosed bag."
    )
