"""Fixtures every layer's tests share: the paper's reference mission, loaded once, and its headless flight."""

from __future__ import annotations

from pathlib import Path

import pytest

from uav_model.mission import Mission, load_mission

REFERENCE = Path(__file__).resolve().parents[1] / "missions" / "paper_reference.yaml"


@pytest.fixture(scope="session")
def reference_mission() -> Mission:
    """missions/paper_reference.yaml, loaded (a frozen Mission: safe to share)."""
    return load_mission(REFERENCE)


@pytest.fixture(scope="session")
def reference_headless(reference_mission: Mission):
    """The reference mission flown by ``companion simulate``'s runner: its RunSummary."""
    from companion.planning.runner import simulate

    return simulate(reference_mission).summary
