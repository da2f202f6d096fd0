"""The packages' layers (docs/architecture.md): every import of ours points down, none up.

Layer 0 is what every package shares (es_common: array type aliases, the lazy public face),
importing nothing of ours. Layer 1 is the contract (es_msgs_py), what every node runs on
(es_node_runtime) and the shared physics (es_physics), none importing another; layer 2 the
roles (es_sim_plant, es_thermal, es_feedforward, es_recordings: they never import each other),
layer 3 the offline calibration
(es_calibration) beside the bring-up and evaluation (es_bringup): nothing under src/ imports
either, and they never import each other (the bring-up runs the calibration tool as an
executable). Read from the source with ast, every module of every package (launch files
included), so a new import that breaks the rule fails here with its file and line.

No import cycle either, between modules of any packages: every import counts, also one inside
a function (a lazy import that closes a cycle still ties the two modules together).

Below the layers, each package.xml against what its code and its tests import (one map of
import to rosdep key: tests/support/workspace.py).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from support.workspace import (
    OPTIONAL_KEYS,
    ROOT,
    SRC,
    declared,
    external_imports,
    key_of,
    package_tests,
    packages,
)
from support.workspace import modules as _modules
from support.workspace import packages as _packages

#: Layer of each package; a module may import packages of a lower layer only.
LAYER = {
    "es_common": 0,
    "es_msgs_py": 1,
    "es_node_runtime": 1,
    "es_physics": 1,
    "es_sim_plant": 2,
    "es_thermal": 2,
    "es_feedforward": 2,
    "es_recordings": 2,
    "es_calibration": 3,
    "es_bringup": 3,
}


def _imports_of_ours(path: Path) -> list[tuple[int, str]]:
    """Return (line, package) of every absolute import of one of our packages."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found += [(node.lineno, n.split(".")[0]) for n in names if n.split(".")[0] in LAYER]
    return found


def _uses() -> dict[str, set[str]]:
    return {
        package: {
            used
            for path in _modules(package)
            for _, used in _imports_of_ours(path)
            if used != package
        }
        for package in _packages()
    }


def _module_name(path: Path) -> str:
    """Return the dotted name of a module under ``src/<package>/`` (``es_msgs_py.bag.reader``)."""
    names = list(path.relative_to(SRC / path.relative_to(SRC).parts[0]).with_suffix("").parts)
    return ".".join(names[:-1] if names[-1] == "__init__" else names)


def _import_graph() -> dict[str, set[str]]:
    """Return, for every module of ours, the modules of ours it imports (anywhere in it)."""
    paths = {
        _module_name(path): path
        for package in _packages()
        for path in _modules(package)
        if path.parts[len(SRC.parts) + 1] == package  # the package's modules, not launch files
    }
    graph: dict[str, set[str]] = {}
    for name, path in paths.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets |= {alias.name for alias in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative: from the package, one level up per extra dot
                    anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*anchor, *([base] if base else [])])
                # `from a import b` imports the module a.b when there is one, else a name of a
                targets |= {
                    f"{base}.{alias.name}" if f"{base}.{alias.name}" in paths else base
                    for alias in node.names
                }
        graph[name] = {t for t in targets if t in paths and t != name}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Return the strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for target in sorted(graph[node]):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_every_package_has_a_layer() -> None:
    assert set(_packages()) == set(LAYER), "place a new package in LAYER and the doc's table"


def test_imports_point_only_down() -> None:
    wrong = [
        f"{path.relative_to(ROOT)}:{line}: {package} (layer {LAYER[package]}) imports "
        f"{used} (layer {LAYER[used]})"
        for package in _packages()
        for path in _modules(package)
        for line, used in _imports_of_ours(path)
        if used != package and LAYER[used] >= LAYER[package]
    ]
    assert not wrong, "\n".join(wrong)


def test_the_roles_and_the_bottom_use_what_the_doc_says() -> None:
    uses = _uses()
    assert uses["es_common"] == set()
    common = {"es_common"}
    assert uses["es_msgs_py"] | uses["es_node_runtime"] | uses["es_physics"] <= common
    bottom = {"es_msgs_py", "es_node_runtime", "es_physics"} | common
    assert uses["es_sim_plant"] <= bottom
    assert uses["es_feedforward"] <= bottom
    assert uses["es_thermal"] <= bottom
    assert uses["es_recordings"] <= {"es_msgs_py", "es_node_runtime"} | common
    assert uses["es_calibration"] <= bottom | {"es_feedforward", "es_recordings", "es_thermal"}
    assert not any({"es_bringup", "es_calibration"} & used for used in uses.values())


def test_no_module_imports_itself_through_others() -> None:
    graph = _import_graph()
    assert "es_recordings.labimport.sources" in graph  # the graph holds our modules
    assert "es_msgs_py.bag.codec" in graph["es_msgs_py.bag"]  # `from a.b import c`: module a.b.c
    cycles = _cycles(graph)
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_the_cycle_check_finds_a_cycle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]


RUN_TAGS = ("depend", "exec_depend")
TEST_TAGS = ("depend", "exec_depend", "test_depend")


def _needed(package: str, files: list[Path]) -> dict[str, tuple[str, Path]]:
    """Return key -> (import, file) of everything ``files`` import, but ``package`` itself."""
    needed: dict[str, tuple[str, Path]] = {}
    for name, path in external_imports(files).items():
        try:
            key = key_of(name)
        except KeyError:
            raise AssertionError(
                f"{path.relative_to(ROOT)} imports {name}: add its rosdep key to "
                "IMPORT_KEY (tests/support/workspace.py)"
            ) from None
        if key is not None and key != package:
            needed.setdefault(key, (name, path))
    return needed


@pytest.mark.parametrize("package", packages())
def test_package_xml_declares_what_its_code_imports(package: str) -> None:
    """Every import of the package's code has its rosdep key as a run dependency; optional
    features' keys under their condition (REP 149), every other key unconditional."""
    have = declared(package, RUN_TAGS)
    wrong = []
    for key, (name, path) in sorted(_needed(package, _modules(package)).items()):
        want = f"${OPTIONAL_KEYS[key]} == 1" if key in OPTIONAL_KEYS else None
        if key not in have:
            wrong.append(f"lacks <exec_depend>{key}</exec_depend> ({name}, {path.name})")
        elif have[key] != want:
            wrong.append(f"{key}: condition {have[key]!r}, expected {want!r}")
    assert not wrong, f"{package}/package.xml: " + "; ".join(wrong)


@pytest.mark.parametrize("package", packages())
def test_package_xml_declares_no_python_library_it_does_not_import(package: str) -> None:
    """A Python library key no module imports is a stale declaration (ROS message packages
    may be loaded by type name, es_msgs_py.topics.message_class, so only python3-* keys)."""
    used = set(_needed(package, _modules(package)))
    stale = sorted(
        key for key in declared(package, RUN_TAGS) if key.startswith("python3-") and key not in used
    )
    assert not stale, f"{package}/package.xml declares {stale}, imported nowhere in its code"


@pytest.mark.parametrize("package", packages())
def test_package_xml_declares_what_its_tests_import(package: str) -> None:
    """``colcon test`` runs tests/<package> (src/conftest.py) in the environment of the
    package's dependencies: what those tests import (tests/conftest.py included) is declared.
    A package of ours only when its layer is lower: a test_depend across a layer, or up, can
    close a cycle (es_feedforward's tests use es_sim_plant and the other way round), which
    colcon refuses; those tests run in the sourced workspace (docs/ros2-install.md)."""
    assert (ROOT / "tests" / package).is_dir(), f"tests/{package} missing: colcon test runs it"
    files = [ROOT / "tests" / "conftest.py", *package_tests(package)]
    have = declared(package, TEST_TAGS)
    cycles = {other for other in _packages() if LAYER[other] >= LAYER[package]}
    missing = sorted(
        f"{key} ({name}, {path.name})"
        for key, (name, path) in _needed(package, files).items()
        if key not in have and key not in cycles
    )
    assert not missing, f"{package}/package.xml lacks test dependencies: {missing}"
    cyclic = sorted(set(declared(package, ("test_depend",))) & cycles)
    assert not cyclic, f"{package}/package.xml: test_depend {cyclic} not below its layer"
