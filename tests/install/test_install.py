"""Both install paths: `colcon build` of the workspace, and the README's pip set-up (.venv).

The executables each package must install are read from the ``EXECUTABLES`` table of its
setup.py, so this test follows the packages as they grow.
"""

from __future__ import annotations

import ast
import os
import re
import signal
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix, get_packages_with_prefixes
from diagnostic_msgs.msg import DiagnosticArray
from ros_wheels_bootstrapper import get_ros_paths
from support.ros import NodeProcess, wait_matched, wait_until
from support.ros import test_node as ros_node

from es_msgs_py import topics

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = sorted(p.name for p in (ROOT / "src").iterdir() if (p / "package.xml").is_file())
PYTHON_DIR = f"python{sys.version_info.major}.{sys.version_info.minor}"
#: Executables that are long-running nodes; every other executable is a CLI tool.
NODE_EXECUTABLES = ("record",)


def _setup_constant(package: str, name: str) -> object:
    """Return the literal value of ``NAME = ...`` in ``src/<package>/setup.py``, else None."""
    tree = ast.parse((ROOT / "src" / package / "setup.py").read_text())
    for stmt in tree.body:
        if isinstance(stmt, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == name for t in stmt.targets
        ):
            return ast.literal_eval(stmt.value)
    return None


def executable_modules(package: str) -> dict[str, str]:
    """Return ``EXECUTABLES = {exe: module}`` of ``src/<package>/setup.py``."""
    table = _setup_constant(package, "EXECUTABLES")
    assert isinstance(table, dict), f"src/{package}/setup.py has no EXECUTABLES table"
    return table


def moved_executables(package: str) -> list[str]:
    """Return ``MOVED``: launchers kept one release under an old name (they say where to)."""
    moved = _setup_constant(package, "MOVED")
    return list(moved) if isinstance(moved, list) else []


def console_script(package: str, exe: str) -> str:
    """Return the console script (setup.py's entry points) behind ``lib/<package>/<exe>``."""
    return f"{package}-{exe.replace('_', '-')}"


def executables_of(package: str) -> list[str]:
    """Return the keys of ``EXECUTABLES = {...}`` in ``src/<package>/setup.py``."""
    return sorted(executable_modules(package))


ALL_EXECUTABLES = [(pkg, exe) for pkg in PACKAGES for exe in executables_of(pkg)]


def is_node(exe: str) -> bool:
    return exe.endswith("_node") or exe in NODE_EXECUTABLES


def assert_installed(prefix: Path, package: str) -> None:
    """Check the files `ros2 run`/`ros2 pkg` rely on under one install prefix."""
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / package).is_file()
    assert (prefix / "share" / package / "package.xml").is_file()
    for exe in executables_of(package):
        launcher = prefix / "lib" / package / exe
        assert launcher.is_file(), f"{launcher} missing"
        assert os.access(launcher, os.X_OK), f"{launcher} is not executable"


def test_every_package_lists_executables_with_modules() -> None:
    assert PACKAGES == [
        "es_bringup", "es_calibration", "es_common", "es_feedforward", "es_msgs_py",
        "es_node_runtime", "es_physics", "es_recordings", "es_sim_plant", "es_thermal",
    ]
    for package, exe in ALL_EXECUTABLES:
        module = executable_modules(package)[exe]
        script = ROOT / "src" / package / "scripts" / exe
        assert script.is_file(), f"{script} missing"
        console = f'"$prefix/bin/{console_script(package, exe)}" "$@"'
        assert f"exec {console}" in script.read_text(), f"{script} runs another program"
        assert (ROOT / "src" / package / f"{module.replace('.', '/')}.py").is_file(), (
            f"module {module} does not exist yet"
        )


# --- colcon -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Build the workspace with colcon (from PyPI, in the venv) into a temporary directory."""
    base = tmp_path_factory.mktemp("colcon")
    command = [
        sys.executable, "-m", "colcon", "--log-base", str(base / "log"), "build",
        "--base-paths", str(ROOT / "src"),
        "--build-base", str(base / "build"), "--install-base", str(base / "install"),
    ]  # fmt: skip
    proc = subprocess.run(
        command, cwd=base, capture_output=True, text=True, timeout=300, check=False
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return base / "install"


@pytest.mark.parametrize("package", PACKAGES)
def test_colcon_build_installs_package(colcon_install: Path, package: str) -> None:
    assert_installed(colcon_install / package, package)
    site = colcon_install / package / "lib" / PYTHON_DIR / "site-packages" / package
    assert (site / "__init__.py").is_file()


def _clean_shell(
    install: Path, line: str, tmp_path: Path, underlay: dict[str, str] | None = None
) -> str:
    """Run ``line`` in bash after ``source install/setup.bash``, as a fresh login would: no
    virtual environment, PATH the system's with a decoy ``python3`` first (it fails), so a
    launcher that ran the python3 on PATH fails. ``underlay``: variables of an underlay's
    setup.bash (/opt/ros/jazzy on a ROS install). Returns stdout; fails on a non-zero exit."""
    decoy = tmp_path / "decoy"
    decoy.mkdir(exist_ok=True)
    (decoy / "python3").write_text("#!/bin/sh\necho 'decoy python3 from PATH' >&2\nexit 97\n")
    (decoy / "python3").chmod(0o755)
    env = {"HOME": str(tmp_path), "PATH": f"{decoy}:/usr/bin:/bin", **(underlay or {})}
    proc = subprocess.run(
        ["bash", "-c", f"source {install}/setup.bash && {line}"], env=env, capture_output=True,
        text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def _shebang(install: Path, package: str, exe: str) -> str:
    script = install / package / "bin" / console_script(package, exe)
    return script.read_text().splitlines()[0]


def test_colcon_launcher_built_in_a_venv_runs_from_any_shell(
    colcon_install: Path, tmp_path: Path
) -> None:
    """Built inside a virtual environment (this one), `ros2 run` works from a shell without
    it: the launcher runs the console script, whose first line is the venv's Python."""
    assert _shebang(colcon_install, "es_recordings", "record") == f"#!{sys.executable}"
    launcher = colcon_install / "es_recordings" / "lib" / "es_recordings" / "record"
    assert "usage: record" in _clean_shell(colcon_install, f"{launcher} --help", tmp_path)


def test_colcon_launcher_built_on_the_system_python_runs_from_any_shell(tmp_path: Path) -> None:
    """Built by the system Python (this venv's base interpreter, as on a ROS install), the
    launchers run it, not a python3 on PATH; the ROS underlay (here: this venv's
    site-packages on PYTHONPATH, what /opt/ros/jazzy/setup.bash does) provides rclpy."""
    system = Path(sys.base_prefix) / "bin" / PYTHON_DIR
    # the underlay, as /opt/ros/jazzy/setup.bash sets it for its packages: this venv's
    # site-packages on PYTHONPATH, the ROS wheels' libraries on LD_LIBRARY_PATH (what their
    # .pth file does for this venv's own interpreter only)
    sites = [p for p in sys.path if p.startswith(sys.prefix) and p.endswith("site-packages")]
    underlay = {"PYTHONPATH": os.pathsep.join(sites), "LD_LIBRARY_PATH": get_ros_paths()}
    # the two packages record needs: a whole build costs CI time and shows nothing more
    command = [
        str(system), "-m", "colcon", "--log-base", str(tmp_path / "log"), "build",
        "--base-paths", str(ROOT / "src" / "es_msgs_py"), str(ROOT / "src" / "es_recordings"),
        "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install"),
    ]  # fmt: skip
    proc = subprocess.run(command, cwd=tmp_path, env={**os.environ, **underlay},
                          capture_output=True, text=True, timeout=300, check=False)  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    install = tmp_path / "install"
    assert _shebang(install, "es_recordings", "record") == f"#!{system}"
    launcher = install / "es_recordings" / "lib" / "es_recordings" / "record"
    out = _clean_shell(install, f"{launcher} --help", tmp_path, underlay)
    assert "usage: record" in out


def test_colcon_launcher_built_with_symlink_install_runs_from_any_shell(tmp_path: Path) -> None:
    """`colcon build --symlink-install` (setup.py develop): lib/<pkg>/<exe> is a symlink into
    the build tree, the console script is in install/<pkg>/bin/ and the package is found
    through the develop hook; the launcher still runs from a clean shell."""
    # the two packages record needs, as in the system-Python test above
    command = [
        sys.executable, "-m", "colcon", "--log-base", str(tmp_path / "log"), "build",
        "--symlink-install",
        "--base-paths", str(ROOT / "src" / "es_msgs_py"), str(ROOT / "src" / "es_recordings"),
        "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install"),
    ]  # fmt: skip
    proc = subprocess.run(
        command, cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    install = tmp_path / "install"
    launcher = install / "es_recordings" / "lib" / "es_recordings" / "record"
    assert launcher.is_symlink(), f"{launcher} was copied: not a symlink install"
    assert _shebang(install, "es_recordings", "record") == f"#!{sys.executable}"
    # by its absolute path and relative to the working directory, as `ros2 run` and a user do
    assert "usage: record" in _clean_shell(install, f"{launcher} --help", tmp_path)
    relative = launcher.relative_to(tmp_path)
    assert "usage: record" in _clean_shell(install, f"cd {tmp_path} && {relative} --help", tmp_path)


@pytest.mark.timeout(1200)  # ten packages' pytest starts: 254 s alone at load 12, over the 300 s guard beside others
def test_colcon_test_runs_every_package_s_tests(colcon_install: Path, tmp_path: Path) -> None:
    """`colcon test` runs each package's tests (tests/<package>, src/conftest.py) with pytest
    and `colcon test-result` counts them: not 0 for any package. Bounded: the first test of
    each file (support/colcon_sample.py), neither slow nor dds; the whole run is
    docs/ros2-install.md's."""
    base = colcon_install.parent
    results = tmp_path / "test_results"
    colcon = f"{sys.executable} -m colcon --log-base {tmp_path / 'log'}"
    line = (
        f"{colcon} test --base-paths {ROOT / 'src'} --build-base {base / 'build'} "
        f"--install-base {colcon_install} --test-result-base {results} "
        "--pytest-args -m 'not slow and not dds' -p support.colcon_sample"
    )
    # support/ importable for -p (tests/conftest.py adds it only once loaded)
    env = {**os.environ, "PYTHONPATH": str(ROOT / "tests")}
    proc = subprocess.run(["bash", "-c", f"source {colcon_install}/setup.bash && {line}"],
                          env=env, capture_output=True, text=True, timeout=1800, check=False)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    counts: dict[str, int] = {}
    for package in PACKAGES:
        suite = ET.parse(results / package / "pytest.xml").getroot().find("testsuite")
        assert suite is not None, package
        counts[package] = int(suite.get("tests", "0"))
    assert all(counts.values()), counts
    report = subprocess.run(
        [sys.executable, "-m", "colcon", "test-result", "--test-result-base", str(results),
         "--verbose"], capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert report.returncode == 0, report.stdout[-3000:]
    summary = re.search(r"Summary: (\d+) tests, 0 errors, 0 failures", report.stdout)
    assert summary is not None, report.stdout[-3000:]
    assert int(summary.group(1)) == sum(counts.values()) > 0


# --- the README's pip set-up ------------------------------------------------------------------


VENV = Path(sys.prefix)


@pytest.mark.parametrize("package", PACKAGES)
def test_venv_install_has_ament_files(package: str) -> None:
    assert_installed(VENV, package)


def test_ament_index_lists_every_executable(monkeypatch: pytest.MonkeyPatch) -> None:
    """Emulate `ros2 pkg executables <pkg>` with AMENT_PREFIX_PATH=<venv>."""
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(VENV))
    assert set(PACKAGES) <= set(get_packages_with_prefixes())
    for package in PACKAGES:
        lib = Path(get_package_prefix(package)) / "lib" / package
        # ros2pkg lists every executable file under <prefix>/lib/<pkg>.
        # A library package (es_common, es_physics, es_node_runtime) has no lib/<pkg> folder at all.
        files = lib.iterdir() if lib.is_dir() else iter(())
        found = sorted(p.name for p in files if p.is_file() and os.access(p, os.X_OK))
        assert found == sorted([*executables_of(package), *moved_executables(package)]), package


@pytest.mark.dds
@pytest.mark.parametrize(("package", "exe"), [(p, e) for p, e in ALL_EXECUTABLES if is_node(e)])
def test_node_executable_joins_the_graph_and_exits_on_sigint(
    package: str, exe: str, tmp_path: Path
) -> None:
    args = ["-o", str(tmp_path / "bag"), "/dm/command"] if exe == "record" else []
    with ros_node("es_install_probe") as probe:
        reporters: set[str] = set()

        def on_report(msg: DiagnosticArray) -> None:
            reporters.update(status.name.split(":", 1)[0] for status in msg.status)

        reports = probe.create_subscription(
            DiagnosticArray, topics.DIAGNOSTICS, on_report, topics.DIAGNOSTICS_QOS
        )
        proc = NodeProcess(package, exe, args)
        try:
            # Started and spinning: its diagnostics (every node reports them) arrive.
            wait_matched(probe, [reports], processes=[proc])
            wait_until(probe, lambda: bool(reporters), f"/diagnostics from {exe}", processes=[proc])
        finally:
            code = proc.stop(signal.SIGINT)
    assert code == 0, proc.output()


@pytest.mark.parametrize(("package", "exe"), [(p, e) for p, e in ALL_EXECUTABLES if not is_node(e)])
def test_cli_tool_prints_usage(package: str, exe: str) -> None:
    launcher = VENV / "lib" / package / exe
    proc = subprocess.run(
        [str(launcher), "--help"], capture_output=True, text=True, timeout=120, check=False
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "usage" in proc.stdout.lower(), proc.stdout[-2000:]
