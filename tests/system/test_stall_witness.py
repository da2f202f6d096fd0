"""The benchmark's stall witness: which slow set points began during a stall of the machine."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hosttools.stall_witness import (
    MachineCheck,
    during_stalls,
    load,
    load_all,
    witness_commands,
)

PERIOD = 1e-3  # a 1 kHz paced run


def paced(latency_ms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (sent, received) [s] of set points paced at 1 kHz with these latencies."""
    sent = 100.0 + np.arange(len(latency_ms)) * PERIOD
    return sent, sent + latency_ms * 1e-3


def test_overlap_of_intervals_with_stalls() -> None:
    stalls = np.array([[10.0, 10.03], [20.0, 20.0015]])
    start = np.array([9.0, 9.99, 10.02, 10.04, 19.9995, 20.0])
    end = np.array([9.5, 10.0, 10.05, 10.05, 20.0005, 20.002])
    assert during_stalls(stalls, start, end, 0.001).tolist() == [
        False, True, True, False, True, True]
    # the 1.5 ms stall does not count when only stalls of 2 ms or more do
    assert during_stalls(stalls, start, end, 0.002).tolist() == [
        False, True, True, False, False, False]
    assert not during_stalls(np.empty((0, 2)), start, end, 0.0).any()


def test_an_episode_is_the_machines_when_a_stall_overlapped_its_first_set_point() -> None:
    latency = np.full(1000, 0.3)
    latency[100:120] = np.linspace(20.0, 1.0, 20)  # a 20 ms stall and its backlog
    latency[500:505] = 5.0  # slow while the machine was on time: ours
    sent, received = paced(latency)
    witnessed = np.array([[sent[100] - 0.001, sent[100] + 0.019],  # the machine's stall
                          [sent[800], sent[800] + 0.0006]])  # too short to count
    check = MachineCheck.of(sent, received, witnessed, 2e-3)
    slow = int(np.count_nonzero(latency > 2.0))
    assert (check.slow, check.episodes, check.slow_in_stall) == (slow, 2, slow - 5)
    assert check.stalls == 1
    assert check.longest_ms == pytest.approx(20.0)


def test_nothing_slow_and_no_stall() -> None:
    sent, received = paced(np.full(50, 0.3))
    assert MachineCheck.of(sent, received, np.empty((0, 2)), 2e-3) == MachineCheck(
        0, 0, 0, 0, 0.0)


def test_the_witness_process_writes_its_late_wake_ups_at_sigint(tmp_path: Path) -> None:
    out = tmp_path / "witness.npy"
    proc = subprocess.Popen([sys.executable, "-m", "hosttools.stall_witness", "--out",
                             str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().startswith("watching")  # its stop signals are taken
        time.sleep(0.05)
        os.kill(proc.pid, signal.SIGSTOP)  # a stall of the machine, as the witness sees it
        time.sleep(0.1)
        os.kill(proc.pid, signal.SIGCONT)
        time.sleep(0.1)
    finally:
        os.kill(proc.pid, signal.SIGINT)
        assert proc.wait(10) == 0
    late = load(out)
    assert late.shape[1] == 2
    assert np.max(late[:, 1] - late[:, 0]) >= 0.09  # the stop, at least
    assert load(tmp_path / "none.npy").shape == (0, 2)


def test_one_witness_per_cpu_and_their_files_merged_by_time(tmp_path: Path) -> None:
    commands = witness_commands(tmp_path / "run_witness")
    cpus = sorted(os.sched_getaffinity(0))
    assert [argv[-1] for _, argv in commands] == [str(cpu) for cpu in cpus]
    assert len({path for path, _ in commands}) == len(cpus)
    first, second = tmp_path / "a.npy", tmp_path / "b.npy"
    np.save(first, np.array([[3.0, 3.1], [1.0, 1.2]]))
    np.save(second, np.array([[2.0, 2.5]]))
    merged = load_all([first, second, tmp_path / "missing.npy"])
    assert merged[:, 0].tolist() == [1.0, 2.0, 3.0]
    assert load_all([]).shape == (0, 2)
