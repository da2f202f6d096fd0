"""CPU and memory/IO hogs that load the machine beside a benchmark or the test suite.

Usage (``scripts/stress-test`` starts it beside the suite)::

    .venv/bin/python bench/common/load.py [--cpu N] [--memio N] [--seconds S]

Each CPU hog keeps one core busy; each memory/IO hog keeps 256 MiB resident, touches it and
writes and fsyncs 64 MiB to a scratch file in a loop. stress-ng (Debian package
``stress-ng``) runs them when installed, else Python busy loops do. The hogs are child
processes stopped by their PIDs (SIGTERM, then SIGKILL) when the ``with`` block ends, when
this command gets SIGTERM or SIGINT, or after ``--seconds`` at the latest (every hog also
stops itself then, should its parent be SIGKILLed).
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

#: Resident memory of one memory/IO hog [MiB] and what it writes per loop [MiB].
MEMIO_MIB = 256
WRITE_MIB = 64

_CPU_LOOP = """
import sys, time
end = time.monotonic() + float(sys.argv[1])
while time.monotonic() < end:
    sum(range(10000))
"""

_MEMIO_LOOP = f"""
import os, sys, time
end = time.monotonic() + float(sys.argv[1])
block = bytearray({MEMIO_MIB} * 2**20)
path = os.path.join(sys.argv[2], "hog.bin")
while time.monotonic() < end:
    for i in range(0, len(block), 4096):
        block[i] = (block[i] + 1) % 256
    with open(path, "wb") as f:
        f.write(block[: {WRITE_MIB} * 2**20])
        f.flush()
        os.fsync(f.fileno())
"""


def hog_commands(cpu: int, memio: int, seconds: float, scratch: Path) -> list[list[str]]:
    """Return the command line of each hog (stress-ng when installed, else Python)."""
    limit = str(max(1, round(seconds)))
    if shutil.which("stress-ng"):
        return [["stress-ng", "--cpu", "1", "--timeout", limit, "--quiet"]] * cpu + [
            ["stress-ng", "--vm", "1", "--vm-bytes", f"{MEMIO_MIB}M", "--hdd", "1",
             "--hdd-bytes", f"{WRITE_MIB}M", "--temp-path", str(scratch),
             "--timeout", limit, "--quiet"]
        ] * memio
    return [[sys.executable, "-c", _CPU_LOOP, limit]] * cpu + [
        [sys.executable, "-c", _MEMIO_LOOP, limit, str(scratch)]
    ] * memio


def stop(procs: Sequence[subprocess.Popen[bytes]], grace: float = 3.0) -> None:
    """SIGTERM each hog by its PID, SIGKILL what is left after ``grace`` seconds."""
    for proc in procs:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGTERM)
    deadline = time.monotonic() + grace
    for proc in procs:
        try:
            proc.wait(max(deadline - time.monotonic(), 0.01))
        except subprocess.TimeoutExpired:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()


@contextmanager
def hogs(cpu: int = 2, memio: int = 0, seconds: float = 3600.0) -> Iterator[list[int]]:
    """Run ``cpu`` CPU hogs and ``memio`` memory/IO hogs for the ``with`` block; yield PIDs.

    Raises:
        ValueError: a count is negative or ``seconds`` is not positive.

    """
    if cpu < 0 or memio < 0 or seconds <= 0:
        raise ValueError(f"hogs: need cpu, memio >= 0 and seconds > 0, got {cpu}, {memio}, "
                         f"{seconds}")
    with tempfile.TemporaryDirectory(prefix="es_dm_hog_") as scratch:
        procs = [subprocess.Popen(command, stdout=subprocess.DEVNULL)
                 for command in hog_commands(cpu, memio, seconds, Path(scratch))]
        try:
            yield [p.pid for p in procs]
        finally:
            stop(procs)


def main(argv: Sequence[str] | None = None) -> int:
    """Run hogs until SIGTERM/SIGINT or ``--seconds``; exit 0."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cpu", type=int, default=2, help="CPU hogs (one core each)")
    parser.add_argument("--memio", type=int, default=1, help="memory/IO hogs")
    parser.add_argument("--seconds", type=float, default=3600.0, help="stop after this")
    args = parser.parse_args(argv)
    stopping = False

    def on_signal(_sig: int, _frame: object) -> None:
        nonlocal stopping
        stopping = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        with hogs(args.cpu, args.memio, args.seconds) as pids:
            kind = "stress-ng" if shutil.which("stress-ng") else "Python busy loops"
            print(f"load: {args.cpu} CPU + {args.memio} memory/IO hogs ({kind}), PIDs "
                  f"{' '.join(map(str, pids))}", file=sys.stderr, flush=True)
            end = time.monotonic() + args.seconds
            while not stopping and time.monotonic() < end:
                time.sleep(0.2)
    except ValueError as err:
        parser.error(str(err))
    return 0


if __name__ == "__main__":
    sys.exit(main())
