"""The companion against the stub's PX4 start-up in process (deterministic, no sockets): arming is
TEMPORARILY_REJECTED for PX4's first ~4.2 s after boot, and a vehicle that spawned facing another
way than the mission's initial heading yaws to it before departure.

In process because over UDP at 20x the 4.2 s boot is 0.2 s of wall time, over before a companion
can connect; here the companion is connected from the first step of the sim clock.
"""

from __future__ import annotations

import asyncio
import dataclasses
from pathlib import Path

import pytest

from companion.app.context import RunSettings
from companion.app.flight_plan import prepare
from companion.app.live_run import run_mission
from companion.sitl.inprocess import InProcessFleet, InProcessOptions
from uav_model.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "tests" / "data" / "small_swap.yaml"


async def _fly_from_boot(mission, lines: list[str]):
    """Fly from the stub's first sim step (open_inprocess_fleet would wait out the boot)."""
    fleet = InProcessFleet(mission, InProcessOptions())
    plan = prepare(mission)
    async with asyncio.TaskGroup() as tg:
        driver = tg.create_task(fleet.run())
        try:
            result = await run_mission(plan, fleet.connections(), RunSettings(shared_clock=True), None, lines.append,
                                       open_vehicle=fleet.open_vehicle)
        finally:
            driver.cancel()
    return fleet, result


def _stub_refuses_arming_during_boot() -> bool:
    fleet = InProcessFleet(load_mission(SMALL), InProcessOptions())
    return asyncio.run(fleet.vehicle("a").get_param("COM_DISARM_PRFLT")) == 10.0  # PX4's boot and defaults


@pytest.mark.skipif(not _stub_refuses_arming_during_boot(),
                    reason="the stub arms at once (PX4-faithful boot not merged: branch simcore)")
def test_arming_refused_during_boot_is_retried_and_the_flight_succeeds():
    lines: list[str] = []
    fleet, result = asyncio.run(_fly_from_boot(load_mission(SMALL), lines))
    assert result.success, (result.reason, result.message, lines[-10:])
    for v in fleet.vehicles:
        # The stub reports no healthy sensors until its boot is over (as PX4 SIH), so the companion
        # usually waits that out; an arm that came early was refused, and then it was retried.
        denied = [t for _, t in v.board.texts if "Arming denied" in t]
        if denied:
            assert result.outcomes[v.name].arm_attempts > 1, (v.name, denied)


def test_a_vehicle_facing_the_wrong_way_yaws_to_the_mission_heading_before_departure():
    mission = load_mission(SMALL)
    lines: list[str] = []

    # The stub spawns vehicle a facing north (as PX4 does); the companion's mission says 45 deg.
    north = tuple(dataclasses.replace(v, initial_heading_deg=90.0) if v.name == "a" else v for v in mission.vehicles)
    stub_mission = dataclasses.replace(mission, vehicles=north)

    async def main():
        fleet = InProcessFleet(stub_mission, InProcessOptions())
        plan = prepare(mission)
        async with asyncio.TaskGroup() as tg:
            driver = tg.create_task(fleet.run())
            try:
                return await run_mission(plan, fleet.connections(), RunSettings(), None, lines.append,
                                         open_vehicle=fleet.open_vehicle)
            finally:
                driver.cancel()
    result = asyncio.run(main())
    assert result.success, (result.reason, result.message)
    assert any(line.startswith("a: yawing -45 deg to the mission heading 45") for line in lines), lines
