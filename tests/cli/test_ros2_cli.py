"""Our packages driven by the real ros2 CLI, with the README's own commands.

The commands come from the README's ```bash ros2-tier blocks (so the README and this tier
cannot drift); bags are read with the independent ``mcap`` + ``mcap-ros2-support`` packages
and their counts compared with what every node says it published.
"""

from __future__ import annotations

import re
import shlex
import signal
import subprocess
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from es_bringup.invariants import contract_name
from es_msgs_py import topics

from .conftest import README, Ros2, readme_commands

pytestmark = pytest.mark.dds

STEPS = readme_commands("ros2-tier")
LIVE = readme_commands("ros2-tier-live")
LAUNCHES = [c for c in STEPS if c.startswith("ros2 launch") and "--show-args" not in c]
PUBLISHED = re.compile(r"\[(\w+)\.summary\]: published (/[\w/]+): (\d+)")
#: A node that ended by a signal or with an error shows up in ros2 launch's output like this.
DIED = "process has died"
#: The nodes of the closed-loop graph, as `ros2 node list` shows them.
NODES = ("/plant", "/thermal", "/feedforward", "/record")
#: Amplifier limit of the commands in the bag [V].
V_LIMIT = 350.0


def test_the_readme_holds_every_command_the_tier_must_run() -> None:
    text = "\n".join(STEPS + LIVE)
    for needed in (
        "ros2 pkg executables", "ros2 run", "ros2 launch", "ros2 topic echo --once /dm/command",
        "ros2 topic echo --once /diagnostics", "ros2 topic hz", "ros2 param describe",
        "ros2 param set", "ros2 param dump", "ros2 param load",
    ):  # fmt: skip
        assert needed in text, f"README's ros2-tier blocks lack {needed!r}"
    assert LAUNCHES and LIVE[0].startswith("ros2 launch") and LIVE[0].endswith("&")


def _executables(ros2: Ros2, tmp_path: Path) -> set[tuple[str, ...]]:
    found: set[tuple[str, ...]] = set()
    for line in (c for c in STEPS if c.startswith("ros2 pkg executables")):
        result = ros2.run(line, tmp_path)
        assert result.returncode == 0, result.stderr
        found |= {tuple(row.split()) for row in result.stdout.splitlines() if row.strip()}
    return found


def test_every_executable_the_readme_names_is_installed_and_answers_help(
    ros2: Ros2, tmp_path: Path
) -> None:
    installed = _executables(ros2, tmp_path)
    assert ("es_feedforward", "feedforward_node") in installed
    named = {tuple(m) for m in re.findall(r"ros2 run (\w+) (\w+)", README.read_text())}
    assert named <= installed, f"README names {named - installed}, not installed"
    for line in (c for c in STEPS if c.startswith("ros2 run") and c.endswith("--help")):
        # --help must answer and exit, not start a node (which would run until the bound)
        result = ros2.run(line, tmp_path, timeout=120)
        assert result.returncode == 0, f"{line}: {result.stderr}"
        assert "usage" in result.stdout.lower(), line
        assert "[INFO]" not in result.stdout + result.stderr, f"{line} started a node"


def test_launch_arguments_are_all_described(ros2: Ros2, tmp_path: Path) -> None:
    line = next(c for c in STEPS if c.endswith("--show-args"))
    result = ros2.run(line, tmp_path)
    assert result.returncode == 0, result.stderr
    for name in ("scenario", "mode", "feedforward_params", "bag", "duration", "time_scale",
                 "namespace"):  # fmt: skip
        assert f"'{name}':" in result.stdout
    assert "no description given" not in result.stdout


def published_counts(output: str) -> dict[str, int]:
    """Return what the nodes said they published, per /dm topic (namespaced names mapped)."""
    counts: Counter[str] = Counter()
    for _, topic, n in PUBLISHED.findall(output):
        name = contract_name(topic, topics.DM_TOPICS)
        if name in topics.DM_TOPICS:
            counts[name] += int(n)
    return dict(counts)


def bag_counts(bag: Path) -> dict[str, int]:
    """Read ``bag`` with mcap + mcap-ros2-support; check the commands; count per topic."""
    assert (bag / "metadata.yaml").is_file(), f"{bag} was not closed"
    (storage,) = bag.glob("*.mcap")
    counts: Counter[str] = Counter()
    with storage.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, decoded in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            if channel.topic == topics.COMMAND:
                values = np.asarray(decoded.data, np.float64)
                assert np.all(np.isfinite(values)) and np.all(np.abs(values) <= V_LIMIT)
    return dict(counts)


def _bag_of(line: str, cwd: Path) -> Path:
    for word in shlex.split(line):
        if word.startswith("bag:="):
            return cwd / word.removeprefix("bag:=")
    return cwd / shlex.split(line)[shlex.split(line).index("--bag") + 1]


@pytest.mark.parametrize("line", LAUNCHES + [c for c in STEPS if "bringup --scenario" in c])
def test_a_run_ends_by_itself_with_every_message_in_its_bag(
    ros2: Ros2, tmp_path: Path, line: str
) -> None:
    result = ros2.run(line, tmp_path, timeout=240)
    logs = "".join(p.read_text() for p in tmp_path.glob("log/bringup/*.log"))
    output = result.stdout + result.stderr + logs
    assert result.returncode == 0, output[-3000:]
    assert DIED not in output, output[-3000:]
    assert "stepping anyway" not in output  # every node said it was ready
    published = published_counts(output)
    assert published.get(topics.DISPLACEMENT, 0) > 0, output[-3000:]
    recorded = bag_counts(_bag_of(line, tmp_path))
    assert {t: recorded.get(t, 0) for t in published} == published
    assert "missed 0" in output and not re.search(r"missed [1-9]", output)


def _wait_for(condition: object, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if callable(condition) and condition():
            return True
        time.sleep(0.2)
    return False


def test_the_live_commands_against_a_running_graph_then_ctrl_c(
    ros2: Ros2, tmp_path: Path
) -> None:
    graph_line = LIVE[0].removesuffix("&").strip()
    log = tmp_path / "launch.log"
    launch = ros2.start(graph_line, tmp_path, log)
    try:
        assert _wait_for(lambda: "ready: every input matched" in log.read_text(), 120.0), (
            log.read_text()[-3000:]
        )
        # the ros2 daemon (started here) has seen every node and topic: the graph, no sleep
        assert _wait_for(lambda: _shows_every_topic(ros2, tmp_path), 60.0), "graph never complete"
        for line in LIVE[1:]:
            if line.startswith("ros2 topic hz"):
                _check_hz(ros2, line, tmp_path)
                continue
            result = ros2.run(line, tmp_path, timeout=90)
            assert result.returncode == 0, f"{line}: {result.stderr[-2000:]}"
            _check_output(line, result, tmp_path)
        assert launch.poll() is None, log.read_text()[-3000:]
    finally:
        launch.send_signal(signal.SIGINT)  # Ctrl-C, to the ros2 launch process by PID
        try:
            code = launch.wait(90)
        except subprocess.TimeoutExpired:
            launch.kill()
            raise
    output = log.read_text()
    assert code == 0, output[-3000:]
    assert DIED not in output, output[-3000:]
    assert output.count("process has finished cleanly") == 4, output[-3000:]
    recorded = bag_counts(_bag_of(graph_line, tmp_path))
    assert recorded.get(topics.COMMAND, 0) > 0


def _shows_every_topic(ros2: Ros2, cwd: Path) -> bool:
    shown = set(ros2.run("ros2 topic list", cwd, timeout=60).stdout.split())
    nodes = set(ros2.run("ros2 node list", cwd, timeout=60).stdout.split())
    return set(topics.DM_TOPICS) <= shown and set(NODES) <= nodes


def _check_hz(ros2: Ros2, line: str, cwd: Path) -> None:
    log = cwd / "hz.log"
    hz = ros2.start(line, cwd, log)
    try:
        assert _wait_for(lambda: "average rate" in log.read_text(), 60.0), log.read_text()
    finally:
        hz.send_signal(signal.SIGINT)
        hz.wait(30)
    rates = [float(r) for r in re.findall(r"average rate: ([\d.]+)", log.read_text())]
    assert rates and all(r > 0 for r in rates)


def _check_output(line: str, result: subprocess.CompletedProcess[str], cwd: Path) -> None:
    out = result.stdout
    if line.startswith("ros2 node list"):
        assert set(NODES) <= set(out.split())
    elif "echo --once /dm/command" in line:
        assert "data:" in out and "label: row" in out
    elif "echo --once /diagnostics" in line:
        assert "status:" in out and "name:" in out
    elif line.startswith("ros2 param describe"):
        assert "'inverse_hyperbolic':" in out and "'uncompensated':" in out
    elif line.startswith("ros2 param set"):
        assert "Set parameter successful" in out
    elif line.startswith("ros2 param dump"):
        assert "law:" in (cwd / "feedforward.yaml").read_text()
    elif line.startswith("ros2 param load"):
        # every parameter that may change at run time loads back; read-only ones say so
        failed = re.findall(r"Set parameter (\S+) failed: (.*)", result.stderr)
        assert all("read-only" in reason for _, reason in failed), failed
        loaded = re.findall(r"Set parameter (\S+) successful", out)
        assert {"law.m1", "law.m2", "mode", "v_limit"} <= set(loaded), out
