"""Each package's public face: lazy modules in ``__all__``, errors as specific builtins."""

from __future__ import annotations

import importlib
import subprocess
import sys
from types import ModuleType

import pytest

PACKAGES = (
    "es_msgs_py", "es_node_runtime", "es_physics", "es_feedforward", "es_sim_plant", "es_thermal",
    "es_bringup",
)  # fmt: skip


@pytest.mark.parametrize("name", PACKAGES)
def test_every_public_name_resolves_and_a_misspelt_one_does_not(name: str) -> None:
    package = importlib.import_module(name)
    for public in package.__all__:
        if public != "__version__":
            assert isinstance(getattr(package, public), ModuleType), public
    misspelt = "no_such_module"
    with pytest.raises(AttributeError, match=f"no attribute '{misspelt}'"):
        getattr(package, misspelt)


@pytest.mark.parametrize("name", PACKAGES)
def test_every_error_class_refines_a_builtin_and_is_listed(name: str) -> None:
    errors = importlib.import_module(f"{name}.errors")
    classes = {
        attr for attr, value in vars(errors).items()
        if isinstance(value, type) and issubclass(value, Exception)
    }  # fmt: skip
    assert classes == set(errors.__all__)
    for attr in errors.__all__:
        cls = getattr(errors, attr)
        assert issubclass(cls, ValueError | TypeError), attr
        assert cls.__doc__, attr


@pytest.mark.parametrize("name", PACKAGES)
def test_importing_a_package_and_its_errors_loads_no_rclpy(name: str) -> None:
    code = f"import sys, {name}, {name}.errors; print('rclpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_pure_node_cores_load_no_rclpy() -> None:
    modules = (
        "es_node_runtime.param_spec", "es_sim_plant.lockstep", "es_sim_plant.node_config",
        "es_thermal.node_params", "es_thermal.node_health", "es_thermal.resonance_params",
    )  # fmt: skip
    code = f"import sys; import {', '.join(modules)}; print('rclpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
