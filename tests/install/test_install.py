"""Both install paths: `colcon build` of the workspace, and the README's pip set-up (.venv).

The executables each package must install are read from the ``EXECUTABLES`` table of its
setup.py, so this test follows the packages as they grow.
"""

from __future__ import annotations

import ast
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix, get_packages_with_prefixes
from diagnostic_msgs.msg import DiagnosticArray
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
        "es_bringup", "es_calibration", "es_feedforward", "es_msgs_py", "es_node_runtime",
        "es_physics", "es_recordings", "es_sim_plant", "es_thermal",
    ]
    for package, exe in ALL_EXECUTABLES:
        module = executable_modules(package)[exe]
        script = ROOT / "src" / package / "scripts" / exe
        assert script.is_file(), f"{script} missing"
        assert f"-m {module} " in script.read_text(), f"{script} runs another module"
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


def test_colcon_launcher_runs_from_the_colcon_install(colcon_install: Path) -> None:
    # What `source install/setup.bash && ros2 run es_recordings record --help` does: the
    # launcher finds no python3 in its prefix and runs the one on PATH with the workspace's
    # site-packages on PYTHONPATH.
    site_dirs = [str(p / "lib" / PYTHON_DIR / "site-packages") for p in colcon_install.iterdir()]
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(site_dirs),
        "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
    }
    launcher = colcon_install / "es_recordings" / "lib" / "es_recordings" / "record"
    proc = subprocess.run(
        [str(launcher), "--help"], env=env, capture_output=True, text=True, timeout=60, check=False
    )
    assert proc.returncode == 0, proc.stderr
    assert "usage: record" in proc.stdout
    probe = "import es_recordings.record as m; print(m.__file__)"
    where = subprocess.run(
        ["python3", "-c", probe], env=env, capture_output=True, text=True, timeout=60, check=True
    )
    assert where.stdout.startswith(str(colcon_install))


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
        # A library package (es_physics, es_node_runtime) has no lib/<pkg> folder at all.
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
