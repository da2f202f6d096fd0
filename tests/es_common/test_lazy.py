"""The lazy public face: modules load on first access, a misspelt name is an AttributeError."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest

from es_common.lazy import lazy_modules

INIT = """
from es_common.lazy import lazy_modules

__version__ = "1.0"
__all__ = ["__version__", "heavy", "light"]
__getattr__ = lazy_modules(__name__, __all__)
"""


@pytest.fixture
def package(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[ModuleType]:
    """A package ``lazy_probe`` with two public modules and one private one, imported."""
    root = tmp_path / "lazy_probe"
    root.mkdir()
    (root / "__init__.py").write_text(INIT)
    for name in ("heavy", "light", "_private"):
        (root / f"{name}.py").write_text(f"NAME = {name!r}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in [n for n in sys.modules if n.split(".")[0] == "lazy_probe"]:
        monkeypatch.delitem(sys.modules, name)
    yield importlib.import_module("lazy_probe")
    for name in [n for n in sys.modules if n.split(".")[0] == "lazy_probe"]:
        del sys.modules[name]


def test_a_public_module_loads_on_first_access_only(package: ModuleType) -> None:
    assert "lazy_probe.heavy" not in sys.modules
    assert package.heavy.NAME == "heavy"
    assert sys.modules["lazy_probe.heavy"] is package.heavy
    assert "lazy_probe.light" not in sys.modules  # only what was asked for


def test_a_misspelt_or_private_name_is_an_attribute_error(package: ModuleType) -> None:
    for name in ("hevy", "_private", "__file_name__"):
        with pytest.raises(AttributeError, match=f"module 'lazy_probe' has no attribute '{name}'"):
            getattr(package, name)
    assert "lazy_probe._private" not in sys.modules


def test_a_dunder_name_of_all_is_not_taken_for_a_module() -> None:
    get = lazy_modules("lazy_probe_absent", ["__version__", "mod"])
    with pytest.raises(AttributeError, match="no attribute '__version__'"):
        get("__version__")
    with pytest.raises(ModuleNotFoundError):  # a listed module is imported, not invented
        get("mod")


@pytest.mark.parametrize(
    "name",
    ["es_common", "es_msgs_py", "es_node_runtime", "es_physics", "es_feedforward",
     "es_sim_plant", "es_thermal", "es_bringup"],
)  # fmt: skip
def test_every_lazy_package_uses_the_one_helper(name: str) -> None:
    package = importlib.import_module(name)
    assert package.__getattr__.__qualname__ == "lazy_modules.<locals>.public_module"
