"""The README's colcon path (```bash colcon-tier): build, test and run, as a ROS user would.

The block runs as one bash script in a fresh workspace (``src`` a link to this repository's),
with the ros2 CLI of this tier and the colcon beside it: `colcon build`, `source
install/setup.bash`, `colcon test` (bounded by ``--pytest-args``, as tests/install's check:
the first quick test of each file), `colcon test-result`, then `ros2 pkg prefix`, `ros2 run
... --help` and `ros2 launch ... --show-args` against the built workspace, not the pip install.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from .conftest import ROOT, Ros2, readme_commands

pytestmark = pytest.mark.dds

STEPS = readme_commands("colcon-tier")
#: `colcon test-result --verbose`'s last line: "Summary: 380 tests, 0 errors, 0 failures, ..."
SUMMARY = re.compile(r"Summary: (\d+) tests?, (\d+) errors?, (\d+) failures?")


def test_the_readme_s_colcon_block_builds_tests_and_runs() -> None:
    """The block holds the whole path: build, source, test, results, run."""
    order = [
        "colcon build --base-paths src", "source install/setup.bash",
        "colcon test --base-paths src", "colcon test-result --verbose", "ros2 run ", "ros2 launch ",
    ]  # fmt: skip
    where = [next((i for i, s in enumerate(STEPS) if s.startswith(w)), -1) for w in order]
    assert -1 not in where and where == sorted(where), f"README's colcon-tier block: {STEPS}"


@pytest.mark.timeout(2400)  # a whole build and colcon test: minutes when the machine is shared
def test_the_colcon_path_of_the_readme_works_in_a_fresh_workspace(
    ros2: Ros2, tmp_path: Path
) -> None:
    """Every line of the block succeeds in order; the packages come from the build."""
    (tmp_path / "src").symlink_to(ROOT / "src")
    env = ros2.env()
    env["PYTHONPATH"] = str(ROOT / "tests")  # support/ importable for -p
    # colcon test bounded as the CI check of tests/install: colcon sets PYTEST_ADDOPTS itself,
    # so the bound goes on the README's line (the whole run is docs/ros2-install.md's)
    bounded = [
        f"{s} --pytest-args -m 'not slow and not dds' -p support.colcon_sample"
        if s.startswith("colcon test ") else s
        for s in STEPS
    ]
    script = "set -eo pipefail\n"  # not -u: setup.bash reads unset variables
    script += "\n".join(f"echo '+ {s}' >&2\n{s}" for s in bounded)
    proc = subprocess.run(
        ["bash", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
        timeout=2400, check=False,
    )  # fmt: skip
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0, output[-4000:]
    tests, errors, failures = map(int, SUMMARY.findall(proc.stdout)[-1])
    assert tests > 0 and errors == failures == 0, output[-4000:]
    assert str(tmp_path / "install" / "es_feedforward") in proc.stdout.splitlines()
    assert "usage" in proc.stdout.lower() and "'scenario':" in proc.stdout
