"""The harness's two fixtures, both factories; :mod:`companion.testing.plugin` registers them with pytest."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import TypeVar

import pytest

from companion.testing.processes import Closeable
from companion.testing.runs import CompanionFactory
from companion.testing.stub import SitlFactory

F = TypeVar("F", bound=Closeable)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "slow: end-to-end flights over real UDP (seconds to a minute each)")


def _closed_at_teardown(factory: F) -> Iterator[F]:
    try:
        yield factory
    finally:
        factory.close()


@pytest.fixture
def sitl(tmp_path: Path) -> Iterator[SitlFactory]:
    """Start the SITL stub for a mission on free ports: ``stub = sitl("missions/x.yaml")``."""
    yield from _closed_at_teardown(SitlFactory(tmp_path))


@pytest.fixture
def companion(tmp_path: Path) -> Iterator[CompanionFactory]:
    """Run the companion: ``run = companion(stub)``, ``companion("missions/x.yaml")``, ``companion.start(stub)``."""
    yield from _closed_at_teardown(CompanionFactory(tmp_path))
