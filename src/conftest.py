"""Map each package to its tests for ``colcon test``: tests/<package>/ of the workspace.

colcon runs ``python -m pytest`` with no path in ``src/<package>`` (every setup.py declares
pytest as its test dependency, so colcon picks its pytest step). pytest then finds the
workspace's one configuration, pyproject.toml (markers, addopts, timeout), and would collect
``src/<package>`` itself, which holds no tests; this hook points it at ``tests/<package>``
instead, where tests/conftest.py gives the same isolation as ``./scripts/test``. Why mapped,
not moved: docs/ros2-install.md ("Tests").
"""

from __future__ import annotations

from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parent


def pytest_configure(config: pytest.Config) -> None:
    """Collect tests/<package> when pytest was started without paths in src/<package>."""
    here = config.invocation_params.dir
    if here.parent == SRC and config.args == [str(here)]:
        config.args[:] = [str(SRC.parent / "tests" / here.name)]
