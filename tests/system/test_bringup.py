"""The bring-up as users start it (installed launcher): a failing node, bad arguments."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

LAUNCHER = Path(sys.prefix) / "lib" / "es_sim_plant" / "bringup"


def run(*args: str, timeout: float = 90.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(LAUNCHER), *args], capture_output=True, text=True, timeout=timeout, check=False
    )


@pytest.mark.dds
def test_a_node_that_dies_stops_the_graph_with_a_clear_reason(tmp_path: Path) -> None:
    result = run(
        "--scenario", "thesis_ac", "--bag", str(tmp_path / "bag"), "--log-dir",
        str(tmp_path / "logs"), "--quiet", "--feedforward-param", "mode:=no_such_mode",
    )  # fmt: skip
    assert result.returncode == 1
    assert "feedforward exited unexpectedly with exit code 2" in result.stderr
    assert "no_such_mode" in result.stderr  # the node's own last log lines are shown
    # the others were stopped cleanly: the recorder closed its bag
    assert (tmp_path / "bag" / "metadata.yaml").is_file()
    assert "bag closed" in (tmp_path / "logs" / "record.log").read_text()


def test_bad_arguments_give_one_line_and_exit_2(tmp_path: Path) -> None:
    (tmp_path / "bag").mkdir()
    result = run("--scenario", "thesis_ac", "--bag", str(tmp_path / "bag"))
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1
    assert "exists already" in result.stderr
    result = run("--scenario", "thesis_ac", "--plant-param", "duration=3")
    assert result.returncode == 2
    assert "NAME:=VALUE" in result.stderr
