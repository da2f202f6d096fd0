"""The ros2 CLI tier: which ``ros2`` it drives, and the README commands it runs.

The ``ros2`` is, in this order: ``$ES_DM_ROS2`` (set by ``scripts/test``), the one
``scripts/ros2cli-env`` installed into ``.venv-ros2cli`` (the Jazzy sources in
../shared/ros2-jazzy-tools), or one on PATH (a full ROS 2 install). Without any, the tier
fails in CI (``CI=true``) and is skipped elsewhere, saying why; the summary names the one used.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
#: Fenced README blocks the tier runs: ```bash ros2-tier (one after the other),
#: ```bash ros2-tier-live (against a running graph, started by its first line, ending in &)
#: and ```bash colcon-tier (one script in a fresh colcon workspace).
BLOCK = re.compile(
    r"^```bash (ros2-tier(?:-live)?|colcon-tier)\n(.*?)^```", re.MULTILINE | re.DOTALL
)


def readme_commands(kind: str) -> list[str]:
    """Return the command lines of the README's ``kind`` blocks (continuations joined)."""
    lines: list[str] = []
    for match in BLOCK.finditer(README.read_text(encoding="utf-8")):
        if match.group(1) != kind:
            continue
        text = match.group(2).replace("\\\n", " ")
        lines += [line.strip() for line in text.splitlines() if line.strip()]
    return lines


def find_ros2() -> tuple[Path, str] | None:
    """Return the ``ros2`` to drive and where it comes from, or ``None``."""
    given = os.environ.get("ES_DM_ROS2")
    if given:  # scripts/test's choice: no other is looked for
        if not Path(given).is_file():
            return None
        return Path(given), os.environ.get("ES_DM_ROS2_SOURCE", "ES_DM_ROS2")
    installed = ROOT / ".venv-ros2cli" / "bin" / "ros2"
    if installed.is_file():
        return installed, "the Jazzy sources of ../shared/ros2-jazzy-tools in .venv-ros2cli"
    on_path = shutil.which("ros2")
    if on_path:
        return Path(on_path), "ros2 on PATH (a ROS 2 install)"
    return None


MISSING = (
    "no ros2 CLI: neither ../shared/ros2-jazzy-tools (scripts/ros2cli-env) nor ros2 on PATH"
)


@dataclass(frozen=True)
class Ros2:
    """The ``ros2`` command and the environment it runs our packages in."""

    executable: Path
    source: str

    def env(self) -> dict[str, str]:
        """Return the environment: its bin/ first on PATH, our packages on the ament path."""
        env = dict(os.environ)
        prefix = self.executable.parent.parent
        env["PATH"] = f"{self.executable.parent}{os.pathsep}{env.get('PATH', '')}"
        if (prefix / "lib" / "es_sim_plant").is_dir():  # our packages are in its prefix
            env["AMENT_PREFIX_PATH"] = str(prefix)
        else:  # a system ros2: add .venv, where scripts/bootstrap installed our packages
            paths = [sys.prefix, *filter(None, env.get("AMENT_PREFIX_PATH", "").split(":"))]
            env["AMENT_PREFIX_PATH"] = ":".join(paths)
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        env["PYTHONUNBUFFERED"] = "1"
        return env

    def run(self, line: str, cwd: Path, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
        """Run one README line with bash in ``cwd``; output captured."""
        return subprocess.run(
            ["bash", "-c", line], cwd=cwd, env=self.env(), capture_output=True, text=True,
            timeout=timeout, check=False,
        )  # fmt: skip

    def start(self, line: str, cwd: Path, log: Path) -> subprocess.Popen[bytes]:
        """Start one README line (``exec``: its PID is the command's) writing to ``log``."""
        with log.open("wb") as out:
            return subprocess.Popen(
                ["bash", "-c", f"exec {line}"], cwd=cwd, env=self.env(), stdout=out,
                stderr=subprocess.STDOUT,
            )  # fmt: skip


@pytest.fixture(scope="session")
def ros2() -> Iterator[Ros2]:
    """The ``ros2`` of this tier; the daemon it may start is stopped at the end."""
    found = find_ros2()
    if found is None:
        if os.environ.get("CI") == "true":
            pytest.fail(f"ros2 CLI tier cannot run in CI: {MISSING}", pytrace=False)
        pytest.skip(MISSING)
    tool = Ros2(*found)
    # Ctrl-C must reach the commands even when the suite runs in a background job, which
    # ignores SIGINT: handled here, it is back to the default in every child after exec.
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    yield tool
    tool.run("ros2 daemon stop", ROOT, timeout=60)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Say which ros2 the CLI tier used (or why it could not run)."""
    found = find_ros2()
    if found is None:
        terminalreporter.write_line(f"ros2 CLI tier: NOT RUN: {MISSING}")
    else:
        terminalreporter.write_line(f"ros2 CLI tier used {found[0]} ({found[1]})")
