"""The closed-loop graph split over two hosts: the plant on one, thermal + feedforward +
recorder on the other, two network namespaces joined by a veth pair (hosttools.multihost).

Needs root (CAP_NET_ADMIN) for the namespaces, as CI has; without it the test fails with the
reason, it does not skip. Discovery and data go over UDP across the link only (no shared
memory, no localhost): the Fast DDS initial-peers profile the deployment recipe in
docs/scaling.md describes.
"""

from __future__ import annotations

import re
import subprocess
from dataclasses import replace
from pathlib import Path

import pytest
from hosttools.multihost import NetnsError, fastdds_profile, host_environment, two_hosts

from es_bringup.bringup import GraphConfig, node_specs
from es_bringup.supervisor import Supervisor
from es_msgs_py import topics
from es_msgs_py.bag import read_bag

ROWS, COLS = 4, 4
#: Seconds of sim time: 300 lockstep steps at the scenario's 100 Hz.
DURATION_S = 3.0
BYTES_PER_GRID = 8 * ROWS * COLS


def _finished_counts(plant_log: str) -> tuple[int, dict[str, int]]:
    match = re.search(r"finished: (\d+) steps.*?\); (.*)", plant_log)
    assert match is not None, "plant printed no summary:\n" + plant_log[-1500:]
    counts = {k: int(v) for k, v in (item.rsplit(" ", 1) for item in match.group(2).split(", "))}
    return int(match.group(1)), counts


@pytest.mark.dds
def test_plant_on_one_host_controllers_on_the_other(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    # the plant's command and sync waits are bounds here, not the scenario (no timeout is
    # asserted): far beyond one round trip across the link on a loaded machine
    config = GraphConfig(scenario="dm_exposure", bag=tmp_path / "bag", log_dir=logs,
                         plant={"rows": ROWS, "cols": COLS, "duration": DURATION_S,
                                "command_timeout": 30.0, "sync_timeout": 30.0})
    before, plant = node_specs(config)
    with two_hosts() as (plant_host, control_host):
        supervisor = Supervisor(logs)
        for index, spec in enumerate(before):  # recorder, thermal, feedforward
            env = host_environment(tmp_path, index, control_host.address)
            supervisor.start(replace(spec, command=control_host.command(spec.command, env)))
        env = host_environment(tmp_path, len(before), plant_host.address)
        supervisor.start(replace(plant, command=plant_host.command(plant.command, env)))
        outcome = supervisor.run(wall_timeout=240.0)
        received, sent = control_host.link_bytes()
        namespaces = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True,
                                    check=True).stdout
        assert control_host.namespace in namespaces
    plant_log = (logs / "plant.log").read_text()
    assert outcome.exit_code == 0, f"{outcome.reason}\n{plant_log[-1500:]}"
    assert "peers not all present" not in plant_log  # discovery across the link finished
    steps, counts = _finished_counts(plant_log)
    assert steps == round(DURATION_S * 100)
    assert counts["command_timeouts"] == 0
    assert counts["sync_timeouts"] == 0
    assert counts["rejected"] == 0
    bag = read_bag(tmp_path / "bag", [topics.SETPOINT, topics.COMMAND])
    # every set point the plant sent across the link got its command back across it
    assert len(bag[topics.SETPOINT]) >= steps
    assert len(bag[topics.COMMAND]) == len(bag[topics.SETPOINT])
    assert counts["commands"] >= steps
    # and that traffic went over the veth link: set points in, commands out
    assert received > steps * BYTES_PER_GRID
    assert sent > steps * BYTES_PER_GRID
    # the namespaces are gone with the block
    after = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True,
                           check=True).stdout
    assert control_host.namespace not in after
    assert plant_host.namespace not in after


def test_a_namespace_that_cannot_be_made_is_one_clear_error_and_nothing_stays() -> None:
    # "/" is not allowed in a namespace name: `ip netns add` fails as it does without root
    with pytest.raises(NetnsError, match=r"ip netns add .* failed .*need root"), two_hosts("x/y"):
        pytest.fail("the block must not run")
    assert "esdm-x" not in subprocess.run(["ip", "netns", "list"], capture_output=True,
                                          text=True, check=True).stdout


def test_profile_lists_every_host_and_pins_the_participant() -> None:
    xml = fastdds_profile(["10.0.0.1", "10.0.0.2"], participant_id=3)
    assert xml.count("<locator>") == 2
    assert "<participantID>3</participantID>" in xml
    assert "<useBuiltinTransports>false</useBuiltinTransports>" in xml
    assert "UnicastLocatorList" not in xml  # no own address: every interface up is announced
    own = fastdds_profile(["10.0.0.1", "10.0.0.2"], participant_id=3, address="10.0.0.2")
    # discovery and data both announce the host's own link address, nothing else
    for kind in ("metatrafficUnicastLocatorList", "defaultUnicastLocatorList"):
        listed = re.search(f"<{kind}>(.*?)</{kind}>", own, re.S)
        assert listed is not None, kind
        assert re.findall(r"<address>(.*?)</address>", listed.group(1)) == ["10.0.0.2"]
    with pytest.raises(ValueError, match="participant_id"):
        fastdds_profile(["10.0.0.1"], participant_id=99)
