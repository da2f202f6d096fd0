"""Ctrl-C stops of the closed-loop graph: crashes under ``ros2 launch`` and under the bring-up.

Usage (from the repository root, after ./scripts/bootstrap; ``ros2 launch`` from
``scripts/ros2cli-env``'s .venv-ros2cli, or ES_DM_ROS2=PATH)::

    .venv/bin/python bench/bench_teardown.py [--stops 50] [--only launch bringup]

Each stop starts the graph (``dm_exposure`` 12 x 12, lockstep, recorder on, a run far longer
than the test), waits until the feedforward says it is ready and then a random 0.2-2 s (so
the stop lands at different points of the run), sends SIGINT to the ``ros2 launch`` or
``bringup`` process by PID (what Ctrl-C does) and waits for it to end. A stop is a crash
when a node died (``ros2 launch``: "process has died", e.g. exit -11 after SIGSEGV; the
bring-up: a node that "did not stop cleanly"), a native stack was printed (faulthandler),
the wrapper exited otherwise than cleanly (launch 0, bring-up 130), it took longer than
90 s, or the bag has no metadata.yaml (not closed). :func:`teardown_stops` returns the
counts and stop times; ``main`` prints them as JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Longest wait [s] for the feedforward's readiness, and for a stop to finish.
START_LIMIT_S = 180.0
STOP_LIMIT_S = 90.0
#: Exit codes of a clean Ctrl-C stop.
CLEAN_EXIT = {"launch": 0, "bringup": 130}
#: What a crash leaves in the output.
CRASH_MARKS = ("process has died", "did not stop cleanly", "Fatal Python error", "Segmentation")


@dataclass
class StopResult:
    """The outcome of the stops of one way of starting the graph."""

    kind: str
    stops: int = 0
    crashes: int = 0
    stop_seconds: list[float] = field(default_factory=list)
    crash_notes: list[str] = field(default_factory=list)


def ros2_executable() -> Path | None:
    """Return the ros2 to launch with (ES_DM_ROS2, else .venv-ros2cli's), or None."""
    given = os.environ.get("ES_DM_ROS2")
    candidate = Path(given) if given else ROOT / ".venv-ros2cli" / "bin" / "ros2"
    return candidate if candidate.is_file() else None


def _command(kind: str, bag: Path, log_dir: Path) -> tuple[list[str], dict[str, str]]:
    env = dict(os.environ, PYTHONUNBUFFERED="1", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    if kind == "launch":
        ros2 = ros2_executable()
        if ros2 is None:
            raise FileNotFoundError("no ros2 (run scripts/ros2cli-env or set ES_DM_ROS2)")
        env["AMENT_PREFIX_PATH"] = str(ros2.parent.parent)
        env["PATH"] = f"{ros2.parent}{os.pathsep}{env['PATH']}"
        return [str(ros2), "launch", "es_bringup", "closed_loop.launch.py",
                "scenario:=dm_exposure", "duration:=3600", f"bag:={bag}"], env  # fmt: skip
    bringup = Path(sys.prefix) / "lib" / "es_bringup" / "bringup"
    return [str(bringup), "--scenario", "dm_exposure", "--duration", "3600", "--bag", str(bag),
            "--log-dir", str(log_dir)], env  # fmt: skip


def _ready(output: Path, log_dir: Path) -> bool:
    texts = [output.read_text(errors="replace")]
    feedforward_log = log_dir / "feedforward.log"
    if feedforward_log.is_file():
        texts.append(feedforward_log.read_text(errors="replace"))
    return any("ready: every input matched" in t for t in texts)


def one_stop(kind: str, work: Path, rng: random.Random) -> tuple[float | None, str | None]:
    """Start the graph, Ctrl-C it mid-run; return (stop time [s], crash note or None)."""
    bag, log_dir, output = work / "bag", work / "logs", work / "output.log"
    command, env = _command(kind, bag, log_dir)
    with output.open("wb") as out:
        proc = subprocess.Popen(command, env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + START_LIMIT_S
        while not _ready(output, log_dir):
            if proc.poll() is not None or time.monotonic() > deadline:
                return None, f"did not start: {output.read_text(errors='replace')[-500:]}"
            time.sleep(0.1)
        time.sleep(rng.uniform(0.2, 2.0))  # land the stop at different points of the run
        if proc.poll() is not None:
            return None, f"ended before the stop (exit {proc.returncode})"
        started = time.monotonic()
        proc.send_signal(signal.SIGINT)
        try:
            code = proc.wait(STOP_LIMIT_S)
        except subprocess.TimeoutExpired:
            return None, f"stop took longer than {STOP_LIMIT_S:g} s"
        seconds = time.monotonic() - started
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    texts = [output.read_text(errors="replace")]
    texts += [p.read_text(errors="replace") for p in log_dir.glob("*.log")]
    marks = [m for m in CRASH_MARKS if any(m in t for t in texts)]
    if marks or code != CLEAN_EXIT[kind]:
        return seconds, f"exit {code}, {', '.join(marks) or 'no mark'}"
    if not (bag / "metadata.yaml").is_file():
        return seconds, "bag not closed"
    return seconds, None


def teardown_stops(
    kind: str, stops: int, seed: int = 0, keep: Path | None = None
) -> StopResult:
    """Run ``stops`` Ctrl-C stops of the graph started by ``kind`` (launch or bringup).

    ``keep``: folder that receives the output and node logs of every crashed stop.
    """
    # A background job ignores SIGINT and its children would inherit that: handled here, it
    # is back to the default in every child (exec resets handled signals, not ignored ones).
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    rng = random.Random(seed)
    result = StopResult(kind)
    for index in range(stops):
        with tempfile.TemporaryDirectory(prefix=f"teardown_{kind}_") as tmp:
            seconds, note = one_stop(kind, Path(tmp), rng)
            if note is not None and keep is not None:
                kept = keep / f"{kind}_{index + 1}"
                kept.mkdir(parents=True, exist_ok=True)
                for log in [Path(tmp) / "output.log", *Path(tmp).glob("logs/*.log")]:
                    if log.is_file():
                        shutil.copy(log, kept / log.name)
        result.stops += 1
        if seconds is not None:
            result.stop_seconds.append(seconds)
        if note is not None:
            result.crashes += 1
            result.crash_notes.append(f"stop {index + 1}: {note}")
        print(f"[teardown] {kind} {index + 1}/{stops}: "
              f"{'crash: ' + note if note else 'clean'}", file=sys.stderr, flush=True)  # fmt: skip
    return result


def main(argv: list[str] | None = None) -> int:
    """Run the stops and print the results as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stops", type=int, default=50)
    parser.add_argument("--only", nargs="+", choices=("launch", "bringup"),
                        default=["launch", "bringup"])  # fmt: skip
    parser.add_argument("--keep", type=Path, help="keep the logs of crashed stops here")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    results = [teardown_stops(kind, args.stops, args.seed, args.keep) for kind in args.only]
    print(json.dumps([asdict(r) for r in results], indent=1))
    return 1 if any(r.crashes for r in results) else 0


if __name__ == "__main__":
    raise SystemExit(main())
