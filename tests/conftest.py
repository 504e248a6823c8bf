"""Fixtures every layer's tests share: the paper's reference mission, loaded once, and its headless flight."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# CI draws the same Hypothesis examples on every run, so a landing never hangs on a lucky draw;
# local runs keep exploring new worlds (and print the blob that reproduces a failure).
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("dev", print_blob=True)
settings.load_profile("ci" if os.environ.get("CI") else "dev")

from uav_model.mission import Mission, load_mission

REFERENCE = Path(__file__).resolve().parents[1] / "missions" / "paper_reference.yaml"


@pytest.fixture(scope="session")
def reference_mission() -> Mission:
    """missions/paper_reference.yaml, loaded (a frozen Mission: safe to share)."""
    return load_mission(REFERENCE)


@pytest.fixture(scope="session")
def reference_flight(reference_mission: Mission):
    """The reference mission flown by ``companion simulate``'s runner, once per process: the whole
    run (tracks, ticks, summary), for tests that only read it."""
    from companion.planning.flight.headless import simulate

    return simulate(reference_mission)


@pytest.fixture(scope="session")
def reference_headless(reference_flight):
    """The reference mission flown by ``companion simulate``'s runner: its RunSummary."""
    return reference_flight.summary


# A test that an optional extra decides says so in one form, skipif(reason="needs the ... extra: pip
# install ..."): without the extra it is skipped with the line that brings it, never failed. The
# `extra` marker lets .ci/run run exactly these again once the extras are installed.
EXTRA_REASON = "needs "


def pytest_collection_modifyitems(config, items):
    for item in items:
        if any(str(mark.kwargs.get("reason", "")).startswith(EXTRA_REASON) and "pip install" in mark.kwargs["reason"]
               for mark in item.iter_markers("skipif")):
            item.add_marker(pytest.mark.extra)
