"""Test-wide set-up: isolate ROS 2 traffic of this test process.

Each pytest process gets its own ROS_DOMAIN_ID (one no other es_dm process on the machine
holds, see ``reserve_domain_id``) and discovery stays on localhost, so parallel test runs of
any checkout never see each other.
Node processes started by tests inherit this environment.
"""

from __future__ import annotations

import os
import subprocess

from es_msgs_py.topics import reserve_domain_id

os.environ["ROS_DOMAIN_ID"] = str(reserve_domain_id())
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ.setdefault("PYTHONUNBUFFERED", "1")

import sys
from pathlib import Path

import pytest
from hypothesis import settings

sys.path.insert(0, str(Path(__file__).parent))  # makes tests/support importable as `support`
# the test stand (testing/standgen) where it is not installed (a colcon workspace); an
# installed copy (scripts/bootstrap) comes first
sys.path.append(str(Path(__file__).parents[1] / "testing"))

# No per-example deadline for any property test: on a loaded machine one example can take
# longer than Hypothesis' 200 ms default, which it reports as a failure (DeadlineExceeded, or
# Flaky when the re-run is fast). Speed belongs to the benchmarks.
settings.register_profile("es_dm", deadline=None)
settings.load_profile("es_dm")


@pytest.fixture(scope="session", autouse=True)
def _clean_fastdds_shm() -> None:
    """Clean Fast DDS shared-memory files left by dead processes (`fastdds shm clean`).

    Tests SIGKILL nodes on purpose; the tool removes only files whose owner is gone. A
    fixture, not pytest_sessionstart: under ``colcon test`` this file is loaded during
    collection (src/conftest.py), after the session started.
    """
    tool = Path(sys.prefix) / "bin" / "fastdds"
    if tool.exists():
        subprocess.run([str(tool), "shm", "clean"], capture_output=True, timeout=60, check=False)
