"""The packages' layers (docs/architecture.md): every import of ours points down, none up.

Layer 1 is the contract (es_msgs_py), what every node runs on (es_node_runtime) and the shared
physics (es_physics), none importing another; layer 2 the roles (es_sim_plant, es_thermal,
es_feedforward, es_recordings: they never import each other), layer 3 the offline calibration
(es_calibration) beside the bring-up and evaluation (es_bringup): nothing under src/ imports
either, and they never import each other (the bring-up runs the calibration tool as an
executable). Read from the source with ast, every module of every package (launch files
included), so a new import that breaks the rule fails here with its file and line.
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


def test_package_xml_declares_every_package_it_imports() -> None:
    for package, used in _uses().items():
        tree = ET.parse(SRC / package / "package.xml")
        declared = {e.text for tag in ("depend", "exec_depend") for e in tree.iter(tag)}
        assert used <= declared, f"{package}/package.xml lacks {sorted(used - declared)}"
