"""The bring-up as users start it (installed launcher): a failing node, bad arguments; the
test stand's recorder drain."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from es_bringup.bringup import Bringup, GraphConfig, plant_published_counts
from es_bringup.graph import RECORDED_TOPICS, TEST_STAND_TOPICS
from es_bringup.supervisor import EXIT_FAILURE, Outcome

LAUNCHER = Path(sys.prefix) / "lib" / "es_bringup" / "bringup"


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


def test_a_test_stand_waits_only_for_the_topics_its_recorder_records() -> None:
    # the plant logs every publisher, set points (none on a test stand) included; the
    # recorder reports no count for a topic it does not record, so the drain must skip them
    log = [
        "[INFO] [1.0] [plant.summary]: published /clock: 5001",
        "[INFO] [1.0] [plant.summary]: published /diagnostics: 7",
        "[INFO] [1.0] [plant.summary]: published /dm/command: 5000",
        "[INFO] [1.0] [plant.summary]: published /dm/displacement: 5001",
        "[INFO] [1.0] [plant.summary]: published /dm/heat_load: 200",
        "[INFO] [1.0] [plant.summary]: published /dm/setpoint: 0",
        "[INFO] [1.0] [plant.summary]: published /run0/dm/temperature/raw: 200",
    ]
    assert plant_published_counts(log, TEST_STAND_TOPICS) == {
        "/dm/command": 5000,
        "/dm/displacement": 5001,
        "/dm/heat_load": 200,
        "/dm/temperature/raw": 200,
    }


def test_a_closed_loop_waits_for_the_plant_topics_its_recorder_records() -> None:
    # a lockstep plant is paced by its controllers, not by the recorder: after the run the
    # recorder must have every set point, displacement, heat load and raw sample
    log = [
        "[INFO] [1.0] [plant.summary]: published /clock: 3001",
        "[INFO] [1.0] [plant.summary]: published /dm/displacement: 3001",
        "[INFO] [1.0] [plant.summary]: published /dm/heat_load: 301",
        "[INFO] [1.0] [plant.summary]: published /dm/setpoint: 3000",
        "[INFO] [1.0] [plant.summary]: published /dm/temperature/raw: 301",
    ]
    assert plant_published_counts(log, RECORDED_TOPICS) == {
        "/dm/displacement": 3001,
        "/dm/heat_load": 301,
        "/dm/setpoint": 3000,
        "/dm/temperature/raw": 301,
    }


def test_a_run_whose_bag_has_a_hole_fails(tmp_path: Path) -> None:
    # the recorder's closing lines (one hole it knew of by an announced count) and the
    # plant's own count (one it could not know of: the announcement was lost with the tail)
    (tmp_path / "record.log").write_text(
        "[INFO] [1.0] [record.summary]: /dm/displacement: received 220, written 220, lost "
        "before reception 0, missed 0, not received 0\n"
        "[INFO] [1.0] [record.summary]: /dm/heat_load: received 38, written 38, lost before "
        "reception 0, missed 0, not received 2\n"
    )
    (tmp_path / "plant.log").write_text(
        "[INFO] [1.0] [plant.summary]: published /dm/displacement: 401\n"
        "[INFO] [1.0] [plant.summary]: published /dm/heat_load: 40\n"
    )
    messages: list[str] = []
    bringup = Bringup(GraphConfig(scenario="dm_exposure", bag=tmp_path / "bag", log_dir=tmp_path),
                      announce=messages.append)
    outcome = Outcome(0, "plant finished its run; all stopped cleanly", {})
    bringup._fail_on_holes(outcome)
    assert outcome.exit_code == EXIT_FAILURE
    assert "/dm/heat_load: 2 published messages not received by the recorder" in outcome.reason
    assert "/dm/displacement: plant published 401, recorder received 220" in outcome.reason
    assert len(messages) == 2 and all(m.startswith("bag incomplete: ") for m in messages)


def test_a_run_without_a_hole_keeps_its_outcome(tmp_path: Path) -> None:
    (tmp_path / "record.log").write_text(
        "[INFO] [1.0] [record.summary]: /dm/displacement: received 401, written 401, lost "
        "before reception 0, missed 0, not received 0\n"
    )
    (tmp_path / "plant.log").write_text(
        "[INFO] [1.0] [plant.summary]: published /dm/displacement: 401\n")
    bringup = Bringup(GraphConfig(scenario="dm_exposure", bag=tmp_path / "bag", log_dir=tmp_path),
                      announce=lambda _text: None)
    outcome = Outcome(0, "plant finished its run; all stopped cleanly", {})
    bringup._fail_on_holes(outcome)
    assert outcome == Outcome(0, "plant finished its run; all stopped cleanly", {})
