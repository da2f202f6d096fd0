"""The packages' layers (docs/architecture.md): every import of ours points down, none up.

Layer 1 is the contract (es_msgs_py), what every node runs on (es_node_runtime) and the shared
physics (es_physics), none importing another; layer 2 the roles (es_sim_plant, es_thermal,
es_feedforward, es_recordings: they never import each other), layer 3 the offline calibration
(es_calibration) beside the bring-up and evaluation (es_bringup): nothing under src/ imports
either, and they never import each other (the bring-up runs the calibration tool as an
executable). Read from the source with ast, every module of every package (launch files
included), so a new import that breaks the rule fails here with its file and line.

No import cycle either, between modules of any packages: every import counts, also one inside
a function (a lazy import that closes a cycle still ties the two modules together).
"""

from __future__ import annotations

import ast
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "src"
#: Layer of each package; a module may import packages of a lower layer only.
LAYER = {
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


def _packages() -> list[str]:
    return sorted(p.name for p in SRC.iterdir() if (p / "package.xml").is_file())


def _modules(package: str) -> list[Path]:
    root = SRC / package
    return sorted(
        path
        for path in root.rglob("*.py")
        if path.name != "setup.py" and "build" not in path.relative_to(root).parts
    )


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
    assert uses["es_msgs_py"] == uses["es_node_runtime"] == uses["es_physics"] == set()
    bottom = {"es_msgs_py", "es_node_runtime", "es_physics"}
    assert uses["es_sim_plant"] <= bottom
    assert uses["es_feedforward"] <= bottom
    assert uses["es_thermal"] <= bottom
    assert uses["es_recordings"] <= {"es_msgs_py", "es_node_runtime"}
    assert uses["es_calibration"] <= bottom | {"es_feedforward", "es_recordings"}
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


def test_package_xml_declares_every_package_it_imports() -> None:
    for package, used in _uses().items():
        tree = ET.parse(SRC / package / "package.xml")
        declared = {e.text for tag in ("depend", "exec_depend") for e in tree.iter(tag)}
        assert used <= declared, f"{package}/package.xml lacks {sorted(used - declared)}"
