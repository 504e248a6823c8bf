"""The harness's fixtures, all factories; :mod:`companion.testing.plugin` registers them with pytest."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import TypeVar

import pytest

from companion.testing.processes import Closeable
from companion.testing.px4 import Px4Factory, px4_dir_or_skip
from companion.testing.runs import CompanionFactory
from companion.testing.stub import SitlFactory

F = TypeVar("F", bound=Closeable)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--px4-dir", default=None, metavar="DIR",
                     help="PX4 SITL build (bin/px4 and etc/) for the px4 fixture (default: $PX4_SITL_DIR)")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "slow: end-to-end flights over real UDP (seconds to a minute each)")
    config.addinivalue_line("markers", "px4: flights on real PX4 SITL (skipped unless PX4_SITL_DIR or --px4-dir)")


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


@pytest.fixture
def px4(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Px4Factory]:
    """Start real PX4 SITL for a mission: ``fleet = px4("missions/x.yaml", speedup=4)``; skipped
    (with how to enable it) unless PX4_SITL_DIR or --px4-dir names a PX4 SITL build."""
    yield from _closed_at_teardown(Px4Factory(tmp_path, px4_dir_or_skip(request.config)))
