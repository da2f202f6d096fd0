"""es_node_runtime.middleware: the Fast DDS profile, a shared-memory segment that holds grids."""

from __future__ import annotations

import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from es_node_runtime.middleware import (
    HEARTBEAT_PERIOD_S,
    PROFILES_VARIABLE,
    SHM_SEGMENT_BYTES,
    configure_middleware,
    profile_xml,
    write_profile,
)

NS = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"
GRID_128_BYTES = 128 * 128 * 8


def test_the_profile_adds_a_shared_memory_transport_of_the_segment_size() -> None:
    root = ET.fromstring(profile_xml())
    (descriptor,) = root.iter(f"{NS}transport_descriptor")
    assert descriptor.findtext(f"{NS}type") == "SHM"
    assert int(descriptor.findtext(f"{NS}segment_size") or 0) == SHM_SEGMENT_BYTES
    participant = root.find(f"{NS}participant")
    assert participant is not None and participant.get("is_default_profile") == "true"
    # added to the transports ROS and Fast DDS set up, not instead of them
    assert participant.findtext(f"{NS}rtps/{NS}useBuiltinTransports") == "true"
    used = [e.text for e in participant.iter(f"{NS}transport_id")]
    assert used == [descriptor.findtext(f"{NS}transport_id")]
    assert SHM_SEGMENT_BYTES >= 100 * GRID_128_BYTES  # 100 ms of 128 x 128 at 1 kHz


def test_every_writer_of_the_profile_sends_heartbeats_within_the_period() -> None:
    root = ET.fromstring(profile_xml())
    (writer,) = root.iter(f"{NS}data_writer")
    assert writer.get("is_default_profile") == "true"
    period = writer.find(f"{NS}times/{NS}heartbeatPeriod")
    assert period is not None
    sec, nanosec = (int(period.findtext(f"{NS}{unit}") or -1) for unit in ("sec", "nanosec"))
    seconds = sec + nanosec * 1e-9
    assert seconds == pytest.approx(HEARTBEAT_PERIOD_S)
    # a repair must come while a writer still holds the sample: the contract's history of
    # 1,000 samples lasts 1 s at 1 kHz, Fast DDS's default heartbeat comes every 3 s
    assert HEARTBEAT_PERIOD_S <= 0.1


def test_a_segment_size_that_is_not_positive_is_refused() -> None:
    with pytest.raises(ValueError, match="positive"):
        profile_xml(0)


def test_the_profile_is_written_once_and_rewritten_only_when_it_differs(tmp_path: Path) -> None:
    path = write_profile(tmp_path / "profiles")
    assert path.read_text(encoding="utf-8") == profile_xml()
    stamp = path.stat().st_mtime_ns
    assert write_profile(tmp_path / "profiles") == path
    assert path.stat().st_mtime_ns == stamp
    path.write_text("stale", encoding="utf-8")
    write_profile(tmp_path / "profiles")
    assert path.read_text(encoding="utf-8") == profile_xml()
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no partial file left


def test_configure_sets_the_profile_for_fast_dds(tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(PROFILES_VARIABLE, raising=False)
    monkeypatch.delenv("RMW_IMPLEMENTATION", raising=False)
    path = configure_middleware(tmp_path)
    assert path is not None and path.exists()
    assert os.environ[PROFILES_VARIABLE] == str(path)


def test_a_profile_named_by_the_environment_or_another_rmw_is_left_alone(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(PROFILES_VARIABLE, "/lab/profile.xml")
    assert configure_middleware(tmp_path) is None
    monkeypatch.delenv(PROFILES_VARIABLE)
    monkeypatch.setenv("RMW_IMPLEMENTATION", "rmw_cyclonedds_cpp")
    assert configure_middleware(tmp_path) is None
    assert not list(tmp_path.iterdir())
    assert PROFILES_VARIABLE not in os.environ


def test_an_unwritable_directory_leaves_the_defaults_and_says_so(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.delenv(PROFILES_VARIABLE, raising=False)
    monkeypatch.delenv("RMW_IMPLEMENTATION", raising=False)
    blocker = tmp_path / "file"
    blocker.write_text("", encoding="utf-8")
    assert configure_middleware(blocker / "sub") is None
    assert "profile not written" in capsys.readouterr().err
    assert PROFILES_VARIABLE not in os.environ


NODE_WITH_PROFILE = r"""
import os
import sys
from rclpy.node import Node
from es_node_runtime.node_main import run_node

class Says(Node):
    def __init__(self):
        super().__init__("says_its_profile")
        self.create_timer(0.02, self.spinning)

    def spinning(self):
        print("profile", os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE"), flush=True)
        self.context.try_shutdown()

sys.exit(run_node(Says, []))
"""


@pytest.mark.dds
def test_a_node_run_by_run_node_spins_with_the_profile(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(PROFILES_VARIABLE, raising=False)
    done = subprocess.run([sys.executable, "-c", NODE_WITH_PROFILE], capture_output=True,
                          text=True, timeout=60, check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr
    line = next(x for x in done.stdout.splitlines() if x.startswith("profile"))
    path = Path(line.split(maxsplit=1)[1])
    assert path.read_text(encoding="utf-8") == profile_xml()
    assert "Error" not in done.stderr, done.stderr  # Fast DDS parsed it
