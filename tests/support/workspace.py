"""The workspace's packages as ROS sees them: which exist, what they import, what they declare.

One definition of how an import becomes a rosdep key (``IMPORT_KEY``), read by the check of
every package.xml against its code (tests/install/test_layers.py). Generic: a package is any
``src/<name>`` with a package.xml; its code is ``src/<name>/**.py``, its tests
``tests/<name>/`` (the tests colcon runs for it, see src/conftest.py).
"""

from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "src"
TESTS = ROOT / "tests"

#: rosdep key of every import that is neither ours nor Python's own (``None``: Python's own
#: in a later release, imported behind a version check). Keys resolve on Jazzy / Ubuntu noble
#: (tests/install/test_rosdep.py); a new import fails the package.xml check until it is here.
IMPORT_KEY: dict[str, str | None] = {
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "numba": "python3-numba",
    "yaml": "python3-yaml",
    "matplotlib": "python3-matplotlib",
    "h5py": "python3-h5py",
    "rosbags": "python3-rosbags-pip",
    # backports.zstd (MCAP chunks, Python < 3.14) is a dependency of rosbags: its key brings it
    "backports": "python3-rosbags-pip",
    "compression": None,  # compression.zstd, Python 3.14's standard library
    "dask": "python3-dask-distributed-pip",  # rosdep/es_dm.yaml: not in the rosdistro
    "distributed": "python3-dask-distributed-pip",
    "pytest": "python3-pytest",
    "hypothesis": "python3-hypothesis",
    "rclpy": "rclpy",
    "launch": "launch",
    "launch_ros": "launch_ros",
    "ament_index_python": "ament_index_python",
    "builtin_interfaces": "builtin_interfaces",
    "rcl_interfaces": "rcl_interfaces",
    "rosgraph_msgs": "rosgraph_msgs",
    "std_msgs": "std_msgs",
    "sensor_msgs": "sensor_msgs",
    "diagnostic_msgs": "diagnostic_msgs",
}
#: Keys of optional features: declared with a REP 149 condition on this variable, so a plain
#: ``rosdep install`` leaves them out and ``ES_DM_DASK=1 rosdep install`` brings them.
OPTIONAL_KEYS = {"python3-dask-distributed-pip": "ES_DM_DASK"}
#: Test-support code of the workspace (not ROS packages): an import of it stands for its imports.
TEST_SUPPORT = {"support": TESTS / "support", "standgen": ROOT / "testing" / "standgen",
                "tests": TESTS}  # fmt: skip


def packages() -> list[str]:
    """Return every package of the workspace (``src/<name>/package.xml``)."""
    return sorted(p.name for p in SRC.iterdir() if (p / "package.xml").is_file())


def modules(package: str) -> list[Path]:
    """Return the package's own Python files (launch files included, setup.py not)."""
    root = SRC / package
    return sorted(
        path
        for path in root.rglob("*.py")
        if path.name != "setup.py" and "build" not in path.relative_to(root).parts
    )


def package_tests(package: str) -> list[Path]:
    """Return the Python files of the package's tests, ``tests/<package>/``."""
    return sorted((TESTS / package).rglob("*.py"))


def imports(path: Path) -> list[tuple[int, str]]:
    """Return (line, dotted name) of every absolute import in one file."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found += [(node.lineno, node.module)]
            found += [(node.lineno, f"{node.module}.{alias.name}") for alias in node.names]
    return found


def _support_file(name: str) -> Path | None:
    """Return the test-support file a dotted name imports, if it is one."""
    top, *rest = name.split(".")
    if top not in TEST_SUPPORT:
        return None
    base = TEST_SUPPORT[top].joinpath(*rest)
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def external_imports(files: list[Path]) -> dict[str, Path]:
    """Return each top-level import (not Python's own) of ``files`` and one file that has it.

    An import of the workspace's test support (``support``, ``standgen``) stands for the
    imports of the support module it names, followed through.
    """
    found: dict[str, Path] = {}
    todo, seen = list(files), set(files)
    while todo:
        path = todo.pop()
        for _, name in imports(path):
            support = _support_file(name)
            if support is not None:
                if support not in seen:
                    seen.add(support)
                    todo.append(support)
                continue
            top = name.split(".")[0]
            if top not in sys.stdlib_module_names and top not in TEST_SUPPORT:
                found.setdefault(top, path)
    return found


def declared(package: str, tags: tuple[str, ...]) -> dict[str, str | None]:
    """Return the keys of ``tags`` in the package.xml, each with its condition (or None)."""
    tree = ET.parse(SRC / package / "package.xml")
    return {e.text or "": e.get("condition") for tag in tags for e in tree.iter(tag)}


def key_of(name: str) -> str | None:
    """Return the rosdep key of a top-level import (ours: the package's name).

    Raises:
        KeyError: an import nobody has mapped yet (add it to ``IMPORT_KEY``).

    """
    if name in packages():
        return name
    return IMPORT_KEY[name]
