"""pytest plugin: run only the first selected test of each test file (``-p support.colcon_sample``).

The CI check of ``colcon test`` (tests/install/test_install.py) loads it to prove, within its
time, that every package's mapped tests are collected and reported, without running the whole
suite a second time.
"""

from __future__ import annotations

import pytest


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Keep each file's first item; report the rest as deselected."""
    seen: set[str] = set()
    kept: list[pytest.Item] = []
    dropped: list[pytest.Item] = []
    for item in items:
        (dropped if item.path.as_posix() in seen else kept).append(item)
        seen.add(item.path.as_posix())
    if dropped:
        config.hook.pytest_deselected(items=dropped)
    items[:] = kept
